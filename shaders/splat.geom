#version 330 core
// Splat pass, stage 2 of 3: one screen-space quad (4-vertex strip) per Gaussian from the
// centre and half-axes computed in splat.vert. Pixel (u, v) with v down from the top row maps
// to NDC x = 2u/W - 1, y = 1 - 2v/H (framebuffer rows are flipped on readback).

layout(points) in;
layout(triangle_strip, max_vertices = 4) out;

uniform vec2 u_size;

in vec2 vg_center[];
in vec4 vg_axes[];
in vec2 vg_box[];
in vec3 vg_conic[];
in vec4 vg_color[];

out vec2 v_d;            // pixel offset from the projected mean
flat out vec2 v_box;
flat out vec3 v_conic;
flat out vec4 v_color;

void main() {
    if (vg_box[0].x < 0.0) return;  // culled
    for (int i = 0; i < 4; ++i) {
        vec2 corner = vec2(float(i & 1), float(i >> 1)) * 2.0 - 1.0;
        vec2 d = corner.x * vg_axes[0].xy + corner.y * vg_axes[0].zw;
        vec2 pix = vg_center[0] + d;
        gl_Position = vec4(2.0 * pix.x / u_size.x - 1.0, 1.0 - 2.0 * pix.y / u_size.y, 0.0, 1.0);
        v_d = d;
        v_box = vg_box[0];
        v_conic = vg_conic[0];
        v_color = vg_color[0];
        EmitVertex();
    }
    EndPrimitive();
}
