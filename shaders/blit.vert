#version 330 core
// Attribute-less fullscreen triangle: vertices (-1,-1), (3,-1), (-1,3).
// v_uv.y is flipped so texture row 0 (numpy row 0, the image's top row) lands at the top of the window.
out vec2 v_uv;

void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    v_uv = vec2(p.x, 1.0 - p.y);
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
