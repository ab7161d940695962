#version 450
// A triangle that covers the whole viewport (the importance mask).
void main() {
    float x = (int(gl_VertexIndex) == 1) ? 3.0 : -1.0;
    float y = (int(gl_VertexIndex) == 2) ? 3.0 : -1.0;
    gl_Position = vec4(x, y, 0.5, 1.0);
}
