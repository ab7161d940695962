#version 450
// Occluder depth, pulled in from the edges by ~1/16 pixel: the rasterizer
// snaps vertices to a subpixel grid (1/256 pixel on lavapipe), so without
// this an occluder could cover a pixel centre that ground truth, exact in
// f64, leaves to what lies behind it. The distance to an edge is its
// barycentric coordinate over that coordinate's change per pixel. Only the
// edges scene.vert marks are pulled in: outlines and silhouettes, not edges
// the surface runs on across. The near plane's clipping edge is pulled in
// the same way (depth is 1 there).
layout(location = 0) in vec3 bary;
layout(location = 1) flat in uint erode;

const float ERODE = 1.0 / 16.0;

void main() {
    vec3 reach = fwidth(bary) * ERODE;
    if (((erode & 1u) != 0u && bary.x < reach.x)
        || ((erode & 2u) != 0u && bary.y < reach.y)
        || ((erode & 4u) != 0u && bary.z < reach.z)) {
        discard;
    }
    if (1.0 - gl_FragCoord.z < fwidth(gl_FragCoord.z) * ERODE) {
        discard;
    }
}
