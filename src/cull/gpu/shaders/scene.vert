#version 450
// Occluder depth: the scene's triangles, in scene-local coordinates, moved
// to the eye before the rotation and projection so that f32 keeps its
// precision far from the origin. The eye comes as two f32s (its rounding
// and what the rounding lost): a vertex near the eye then lands within
// rounding of its distance, however far both are from the origin. `w` says which of the triangle's edges
// erode.frag pulls in (bit i: the edge opposite corner i).
layout(location = 0) in vec4 position;
layout(location = 0) out vec3 bary;
layout(location = 1) flat out uint erode;
layout(push_constant) uniform Push {
    mat4 clip_from_view;
    vec4 eye;
    vec4 box_min;
    vec4 box_max;
    vec4 eye_low;
} push;

void main() {
    // Triangles are drawn unindexed, three vertices each.
    int corner = int(gl_VertexIndex) % 3;
    bary = vec3(corner == 0 ? 1.0 : 0.0, corner == 1 ? 1.0 : 0.0, corner == 2 ? 1.0 : 0.0);
    erode = uint(position.w);
    vec3 relative = (position.xyz - push.eye.xyz) - push.eye_low.xyz;
    gl_Position = push.clip_from_view * vec4(relative, 1.0);
}
