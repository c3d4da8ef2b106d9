#version 330 core
// Albedo from the UV atlas with mild lighting from above (front and back lit alike),
// plus the camera-space normal (OpenCV axes) in a second target.
uniform sampler2D u_texture;
uniform float u_ambient;       // e.g. 0.85
uniform vec3 u_light_dir;      // world direction towards the light
uniform bool u_textured;
uniform vec3 u_flat_color;
in vec3 v_normal_world;
in vec3 v_normal_cam;
in vec2 v_uv;
layout(location = 0) out vec4 out_color;
layout(location = 1) out vec4 out_normal;
void main() {
    vec3 n = normalize(v_normal_world);
    vec3 nc = normalize(v_normal_cam);
    if (!gl_FrontFacing) { n = -n; nc = -nc; }
    vec3 albedo = u_textured ? texture(u_texture, v_uv).rgb : u_flat_color;
    float shade = u_ambient + (1.0 - u_ambient) * max(dot(n, normalize(u_light_dir)), 0.0);
    out_color = vec4(albedo * shade, 1.0);
    out_normal = vec4(nc, 1.0);
}
