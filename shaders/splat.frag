#version 330 core
// Splat pass, stage 3 of 3: Gaussian falloff times opacity, premultiplied output for
// back-to-front blending with glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA):
//   dst = src.rgb * alpha + (1 - alpha) * dst.
// As in the training rasterizer: only pixels inside the Gaussian's box count,
// alpha = min(alpha_max, o * exp(-0.5 d^T Sigma^-1 d)) and fragments below alpha_min are dropped
// (0.99 and 1/255).

uniform float u_alpha_min;
uniform float u_alpha_max;

in vec2 v_d;
flat in vec2 v_box;
flat in vec3 v_conic;
flat in vec4 v_color;

out vec4 f_color;

void main() {
    if (abs(v_d.x) > v_box.x || abs(v_d.y) > v_box.y) discard;
    float power = -0.5 * (v_conic.x * v_d.x * v_d.x + v_conic.z * v_d.y * v_d.y) - v_conic.y * v_d.x * v_d.y;
    if (power > 0.0) discard;
    float alpha = min(u_alpha_max, v_color.a * exp(power));
    if (alpha < u_alpha_min) discard;
    f_color = vec4(v_color.rgb * alpha, alpha);
}
