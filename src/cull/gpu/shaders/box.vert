#version 450
// One occlusion query: the 36 vertices of a box's 12 triangles, made from
// the vertex index (no buffer), each face wound counter-clockwise seen
// from outside, so that with back faces culled every pixel of the box
// counts once. The box comes eye-relative from the CPU.
layout(push_constant) uniform Push {
    mat4 clip_from_view;
    vec4 eye;
    vec4 box_min;
    vec4 box_max;
    vec4 eye_low;
} push;

void main() {
    int i = int(gl_VertexIndex);
    int face = i / 6;
    int j = i - face * 6;
    int axis = face / 2;
    float side = float(face - axis * 2);
    float u = (j == 1 || j == 2 || j == 4) ? 1.0 : 0.0;
    float v = (j == 2 || j == 4 || j == 5) ? 1.0 : 0.0;
    // (u, v) runs counter-clockwise about +x, -y, +z; the other faces
    // turn the other way.
    if ((axis == 1) == (side > 0.5)) {
        float w = u;
        u = v;
        v = w;
    }
    vec3 t = axis == 0 ? vec3(side, u, v) : (axis == 1 ? vec3(u, side, v) : vec3(u, v, side));
    vec3 p = mix(push.box_min.xyz, push.box_max.xyz, t);
    gl_Position = push.clip_from_view * vec4(p, 1.0);
}
