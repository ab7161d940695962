#version 450
// Occluder depth: the scene's triangles, in scene-local coordinates, moved
// to the eye before the rotation and projection so that f32 keeps its
// precision far from the origin. The eye comes as two f32s (its rounding
// and what the rounding lost): a vertex near the eye then lands within
// rounding of its distance, however far both are from the origin.
//
// Which edges erode.frag pulls in (bit i: the edge opposite corner i) is
// decided here, per triangle and view: an edge with no neighbour in its
// object, or whose neighbour folds back to the same side of it as seen
// from the eye (a silhouette), is pulled in; an edge the surface continues
// across is not, so a mesh has no cracks inside its outline.
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
// Every vertex, three a triangle, as in the vertex buffer.
layout(std430, set = 0, binding = 0) readonly buffer Positions {
    vec4 positions[];
};
// Per triangle and corner i: the vertex (index into positions) of the
// neighbour across the edge opposite i; NONE when there is none, FLAT when
// the neighbour lies in the triangle's plane (it continues from any view).
layout(std430, set = 0, binding = 1) readonly buffer Apices {
    uint apex[];
};

const uint NONE = 4294967295u;
const uint FLAT = 4294967294u;

vec3 from_eye(uint vertex) {
    return (positions[vertex].xyz - push.eye.xyz) - push.eye_low.xyz;
}

void main() {
    uint v = uint(gl_VertexIndex);
    uint tri = v / 3u;
    uint corner = v - tri * 3u;
    bary = vec3(corner == 0u ? 1.0 : 0.0, corner == 1u ? 1.0 : 0.0, corner == 2u ? 1.0 : 0.0);
    uint q[3] = uint[3](apex[tri * 3u], apex[tri * 3u + 1u], apex[tri * 3u + 2u]);
    uint mask = (q[0] == NONE ? 1u : 0u) | (q[1] == NONE ? 2u : 0u) | (q[2] == NONE ? 4u : 0u);
    // Only a neighbour out of the triangle's plane needs the view to tell
    // a silhouette (most edges of flat walls and proxies have none).
    if (q[0] < FLAT || q[1] < FLAT || q[2] < FLAT) {
        vec3 c0 = from_eye(tri * 3u);
        vec3 c1 = from_eye(tri * 3u + 1u);
        vec3 c2 = from_eye(tri * 3u + 2u);
        for (uint i = 0u; i < 3u; i++) {
            if (q[i] >= FLAT) {
                continue;
            }
            vec3 p = i == 0u ? c0 : (i == 1u ? c1 : c2);
            vec3 a = i == 0u ? c1 : (i == 1u ? c2 : c0);
            vec3 b = i == 0u ? c2 : (i == 1u ? c0 : c1);
            vec3 o = from_eye(q[i]);
            // The plane through the eye and the edge: the surface continues
            // across the edge when the two far corners lie clearly on
            // opposite sides of it; anything else (a fold, or too close to
            // tell) erodes.
            vec3 m = cross(a, b);
            float sp = dot(m, p);
            float so = dot(m, o);
            float tp = 1e-5 * length(m) * length(p);
            float to = 1e-5 * length(m) * length(o);
            bool across = (sp > tp && so < -to) || (sp < -tp && so > to);
            if (!across) {
                mask |= 1u << i;
            }
        }
    }
    erode = mask;
    vec3 here = (position.xyz - push.eye.xyz) - push.eye_low.xyz;
    gl_Position = push.clip_from_view * vec4(here, 1.0);
}
