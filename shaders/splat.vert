#version 330 core
// Splat pass, stage 1 of 3 (splat.vert -> splat.geom -> splat.frag): one invocation per Gaussian.
// Drawn as GL_POINTS through an element buffer holding the Gaussians' ids back to front, so
// gl_VertexID is the Gaussian's id (no vertex attributes). Per-Gaussian data lives in a float
// texture, 5 RGBA32F texels per Gaussian, uploaded once per snapshot version:
//   texel 0: mean.xyz, opacity     texel 1: scale.xyz (std devs), visibility
//   texel 2: quaternion w,x,y,z    texel 3: colour.rgb            texel 4: normal.xyz
// Projection exactly as the training rasterizer (reconstruct/raster/projection.py, 3DGS):
// OpenCV camera x_cam = R x + t; u = fx x/z + cx, v = fy y/z + cy (pixel centres at +0.5);
// cov2d = J W cov3d W^T J^T + eps2d I with J the pinhole Jacobian at x/z, y/z clamped to the
// frustum widened by 30 % on each side; box = pixels within ceil(3 sqrt(lambda_max)) of the mean.
// Highlight (the studio's edit selection): one float vertex attribute per Gaussian, fetched by the
// element index like the texture (1 = selected); with u_highlight on, a selected Gaussian's colour is
// mixed towards u_highlight_rgb in every mode (not in the raw depth pass).

uniform sampler2D u_data;
uniform int u_per_row;            // Gaussians per texture row
uniform mat3 u_R;                 // world -> camera rotation (OpenCV axes)
uniform vec3 u_t;
uniform vec4 u_K;                 // fx, fy, cx, cy in pixels
uniform vec2 u_size;              // image width, height in pixels
uniform vec4 u_lim;               // clamp of x/z to [-lim.x, lim.y], y/z to [-lim.z, lim.w]
uniform float u_near;
uniform float u_far;
uniform float u_eps2d;            // low-pass added to the 2D covariance (0.3)
uniform float u_box_sigma;        // box size in standard deviations (3)
uniform int u_box_square;         // 1: the rasterizer's box, +-ceil(box_sigma sqrt(lambda_max)) on both
                                  //    axes (3DGS); 0: +-box_sigma sqrt(Sigma_ii) per axis
uniform float u_alpha_min;        // alpha below this is discarded (1/255)
uniform int u_mode;               // render_modes.SHADER_CODE
uniform vec2 u_depth_range;       // near (white), far (black) for the depth mode
uniform vec3 u_seen;
uniform vec3 u_unseen;
uniform int u_highlight;          // 1: tint the Gaussians whose a_highlight is set
uniform vec3 u_highlight_rgb;
uniform float u_highlight_mix;

in float a_highlight;             // per Gaussian (by element index): 1 = selected

out vec2 vg_center;               // projected mean, pixels
out vec4 vg_axes;                 // quad half-axes (pixels): corner = center +- axes.xy +- axes.zw
out vec2 vg_box;                  // box half-extent per image axis; x < 0: culled
out vec3 vg_conic;                // inverse 2D covariance (a, b, c) of [[a, b], [b, c]]
out vec4 vg_color;                // rgb, opacity

vec4 fetch(int id, int k) {
    return texelFetch(u_data, ivec2((id % u_per_row) * 5 + k, id / u_per_row), 0);
}

void cull() {
    vg_center = vec2(0.0);
    vg_axes = vec4(0.0);
    vg_box = vec2(-1.0);
    vg_conic = vec3(0.0);
    vg_color = vec4(0.0);
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
}

void main() {
    int id = gl_VertexID;
    vec4 t0 = fetch(id, 0);
    vec4 t1 = fetch(id, 1);
    vec4 q = fetch(id, 2);
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);  // unused: the geometry shader places the quad

    vec3 p = u_R * t0.xyz + u_t;
    float opacity = t0.w;
    if (!(p.z > u_near) || !(p.z < u_far) || !(opacity >= u_alpha_min)) { cull(); return; }

    // rotation of the unit quaternion (w, x, y, z); GLSL matrices are built column by column
    q = q / length(q);
    float w = q.x, x = q.y, y = q.z, z = q.w;
    mat3 Rq = mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
        2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
        2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
    mat3 M = u_R * mat3(Rq[0] * t1.x, Rq[1] * t1.y, Rq[2] * t1.z);  // camera-space R S
    mat3 cov = M * transpose(M);                                      // camera-space covariance

    float fx = u_K.x, fy = u_K.y;
    float rz = 1.0 / p.z;
    float tx = p.z * clamp(p.x * rz, -u_lim.x, u_lim.y);
    float ty = p.z * clamp(p.y * rz, -u_lim.z, u_lim.w);
    vec3 j0 = vec3(fx * rz, 0.0, -fx * tx * rz * rz);  // rows of the 2x3 Jacobian
    vec3 j1 = vec3(0.0, fy * rz, -fy * ty * rz * rz);
    vec3 cj0 = cov * j0;
    vec3 cj1 = cov * j1;
    float a = dot(j0, cj0) + u_eps2d;
    float b = dot(j0, cj1);
    float c = dot(j1, cj1) + u_eps2d;
    float det = a * c - b * b;
    if (!(det > 0.0)) { cull(); return; }

    float mid = 0.5 * (a + c);
    float disc = sqrt(max(mid * mid - det, 0.0));
    float l1 = mid + disc;
    float l2 = max(mid - disc, 0.0);
    vec2 box = u_box_square == 1 ? vec2(ceil(u_box_sigma * sqrt(l1))) : u_box_sigma * sqrt(vec2(a, c));

    // Outside the ellipse d^T Sigma^-1 d = 2 ln(o / alpha_min) alpha < alpha_min: the quad covers
    // that ellipse clipped to the box, as the smaller of the box-clipped axis-aligned rectangle
    // and the ellipse's oriented rectangle (the fragment shader applies the box exactly).
    float k = sqrt(2.0 * log(opacity / u_alpha_min));
    vec2 ext = min(box, k * sqrt(vec2(a, c)));
    vec2 v1 = a >= c ? vec2(l1 - c, b) : vec2(b, l1 - a);  // eigenvector of l1
    float len1 = length(v1);
    v1 = len1 > 0.0 ? v1 / len1 : vec2(1.0, 0.0);
    float s1 = k * sqrt(l1), s2 = k * sqrt(l2);
    vg_axes = s1 * s2 < 0.9 * ext.x * ext.y ? vec4(s1 * v1, s2 * vec2(-v1.y, v1.x)) : vec4(ext.x, 0.0, 0.0, ext.y);

    vec2 mean2d = vec2(fx * p.x * rz + u_K.z, fy * p.y * rz + u_K.w);
    if (mean2d.x + ext.x < 0.0 || mean2d.x - ext.x > u_size.x ||
        mean2d.y + ext.y < 0.0 || mean2d.y - ext.y > u_size.y) { cull(); return; }
    vg_center = mean2d;
    vg_box = box;
    vg_conic = vec3(c, -b, a) / det;

    vec3 col;
    if (u_mode == 0) {
        col = fetch(id, 3).rgb;
    } else if (u_mode == 1) {
        vec3 n = fetch(id, 4).xyz;
        float len = length(n);
        col = len > 1e-12 ? 0.5 * (u_R * (n / len) + 1.0) : vec3(0.5);
    } else if (u_mode == 2) {
        float span = u_depth_range.y - u_depth_range.x;
        col = vec3(clamp((u_depth_range.y - p.z) / (span != 0.0 ? span : 1e-12), 0.0, 1.0));
    } else if (u_mode == 3) {
        col = vec3(1.0);
    } else if (u_mode == 4) {
        col = t1.w > 0.5 ? u_seen : u_unseen;
    } else {
        col = vec3(p.z);  // raw camera depth (render_depth)
    }
    if (u_highlight == 1 && u_mode != 5 && a_highlight > 0.5) col = mix(col, u_highlight_rgb, u_highlight_mix);
    vg_color = vec4(col, opacity);
}
