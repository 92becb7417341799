#version 330 core
// The ray-traced image is already display-ready sRGB-ish 8-bit colour: copy it, force alpha to 1.
// u_exposure (stops, 0: the image as it is) scales its linear light (gamma 2.2) by 2^u_exposure,
// clipped at white: gridrt.app.viewer.blit.exposed computes the same on the CPU for screenshots.
uniform sampler2D u_image;
uniform float u_exposure;
in vec2 v_uv;
out vec4 f_color;

void main() {
    vec3 c = texture(u_image, v_uv).rgb;
    if (u_exposure != 0.0) {
        c = pow(min(pow(c, vec3(2.2)) * exp2(u_exposure), vec3(1.0)), vec3(1.0 / 2.2));
    }
    f_color = vec4(c, 1.0);
}
