#version 330 core
// The ray-traced image is already display-ready sRGB-ish 8-bit colour: copy it, force alpha to 1.
uniform sampler2D u_image;
in vec2 v_uv;
out vec4 f_color;

void main() {
    f_color = vec4(texture(u_image, v_uv).rgb, 1.0);
}
