#version 450
// Depth and stencil only: no colour is written.
void main() {}
