#version 330 core
// Body mesh / skeleton overlay: world positions through the camera's GL matrices
// (Camera.gl_projection() @ Camera.gl_view(), which reproduce K exactly).
// Compiled with "#define FOR_GEOMETRY" when a geometry shader (overlay.geom) follows.

uniform mat4 u_mvp;
uniform mat4 u_view;
uniform float u_point_size;

in vec3 in_pos;

#ifdef FOR_GEOMETRY
out vec3 vg_view;
#define V_OUT vg_view
#else
out vec3 v_view;
#define V_OUT v_view
#endif

void main() {
    V_OUT = (u_view * vec4(in_pos, 1.0)).xyz;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
    gl_PointSize = u_point_size;
}
