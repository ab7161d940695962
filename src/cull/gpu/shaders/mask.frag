#version 450
// The importance mask (Tai & Hsu §3.4): fragments that survive write the
// stencil, masking their pixel off; the important region is discarded, so
// its stencil stays 0. `box_min` = (width, height, type, fill ratio).
// Type 1: the middle half of the screen (in x and y) is important, the
// frame around it is masked off at the fill ratio. Type 2: the middle
// third is important, the frame out to the middle two thirds is masked
// off at half the fill ratio, the outer frame at the fill ratio.
layout(push_constant) uniform Push {
    mat4 clip_from_view;
    vec4 eye;
    vec4 box_min;
    vec4 box_max;
    vec4 eye_low;
} push;

void main() {
    vec2 uv = gl_FragCoord.xy / push.box_min.xy;
    float edge = min(min(uv.x, 1.0 - uv.x), min(uv.y, 1.0 - uv.y));
    float fill = push.box_min.w;
    float density;
    if (push.box_min.z < 1.5) {
        density = edge >= 0.25 ? 0.0 : fill;
    } else {
        density = edge >= 1.0 / 3.0 ? 0.0 : (edge >= 1.0 / 6.0 ? 0.5 * fill : fill);
    }
    // Interleaved gradient noise: an even, deterministic spread of the
    // masked pixels at the asked density.
    float noise = fract(52.9829189 * fract(dot(floor(gl_FragCoord.xy), vec2(0.06711056, 0.00583715))));
    if (noise >= density) {
        discard;
    }
}
