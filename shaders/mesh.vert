#version 330 core
// Textured body mesh for ground-truth images: positions in world space, OpenCV camera.
uniform mat4 u_view;      // world -> OpenGL camera axes
uniform mat4 u_proj;      // OpenGL clip matrix matching the camera intrinsics
uniform mat3 u_cam_rot;   // world -> OpenCV camera rotation (for camera-space normals)
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
out vec3 v_normal_world;
out vec3 v_normal_cam;
out vec2 v_uv;
void main() {
    v_normal_world = in_normal;
    v_normal_cam = u_cam_rot * in_normal;
    v_uv = in_uv;
    gl_Position = u_proj * u_view * vec4(in_position, 1.0);
}
