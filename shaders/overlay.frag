#version 330 core
// u_shading: 0 flat colour, 1 headlight Lambert from screen-space derivatives (solid mesh),
// 2 round point sprite (joints). Output is straight (not premultiplied) alpha.

uniform vec4 u_color;
uniform int u_shading;

in vec3 v_view;
out vec4 f_color;

void main() {
    vec4 c = u_color;
    if (u_shading == 1) {
        vec3 n = cross(dFdx(v_view), dFdy(v_view));
        float len = length(n);
        float lambert = len > 0.0 ? abs(n.z) / len : 1.0;
        c.rgb *= 0.35 + 0.65 * lambert;
    } else if (u_shading == 2) {
        vec2 pc = gl_PointCoord * 2.0 - 1.0;
        if (dot(pc, pc) > 1.0) discard;
    }
    f_color = c;
}
