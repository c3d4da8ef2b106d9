#version 330 core
// Expands each line segment to a screen-aligned quad u_line_width pixels wide (core profiles
// only guarantee 1-pixel GL lines).

layout(lines) in;
layout(triangle_strip, max_vertices = 4) out;

uniform vec2 u_size;        // viewport in pixels
uniform float u_line_width; // pixels

in vec3 vg_view[];
out vec3 v_view;

void main() {
    vec4 p0 = gl_in[0].gl_Position;
    vec4 p1 = gl_in[1].gl_Position;
    if (p0.w <= 0.0 || p1.w <= 0.0) return;  // segment behind the camera: skip
    vec2 s0 = p0.xy / p0.w * 0.5 * u_size;
    vec2 s1 = p1.xy / p1.w * 0.5 * u_size;
    vec2 dir = s1 - s0;
    float len = length(dir);
    dir = len > 1e-6 ? dir / len : vec2(1.0, 0.0);
    vec2 off = vec2(-dir.y, dir.x) * 0.5 * u_line_width / (0.5 * u_size);  // in NDC
    gl_Position = vec4(p0.xy + off * p0.w, p0.zw); v_view = vg_view[0]; EmitVertex();
    gl_Position = vec4(p0.xy - off * p0.w, p0.zw); v_view = vg_view[0]; EmitVertex();
    gl_Position = vec4(p1.xy + off * p1.w, p1.zw); v_view = vg_view[1]; EmitVertex();
    gl_Position = vec4(p1.xy - off * p1.w, p1.zw); v_view = vg_view[1]; EmitVertex();
    EndPrimitive();
}
