"""Textured triangle-mesh rendering (ground truth of the synthetic scenes, mesh overlays).

Renders colour, coverage (mask) and camera-space normals in one pass into float targets, with
``supersample``x supersampling averaged down so that silhouettes are anti-aliased like real
photographs.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

import shaders
from reconstruct.camera import Camera


@dataclass
class MeshImages:
    rgb: np.ndarray  # (H,W,3) float32, composited over the background
    mask: np.ndarray  # (H,W) float32 coverage in [0,1]
    normal: np.ndarray  # (H,W,3) float32 camera-space unit normals (OpenCV axes), 0 outside


class MeshRenderer:
    """Draws one textured mesh topology (faces + per-corner UVs) in many poses and views."""

    def __init__(self, ctx: moderngl.Context, faces: np.ndarray, corner_uvs: np.ndarray,
                 texture: np.ndarray | None = None, *, supersample: int = 2, ambient: float = 0.85) -> None:
        self.ctx = ctx
        self.faces = np.asarray(faces, np.int64)
        self.supersample = int(supersample)
        self.ambient = float(ambient)
        self.prog = ctx.program(vertex_shader=shaders.load("mesh.vert"), fragment_shader=shaders.load("mesh.frag"))
        n_corners = self.faces.size
        uvs = np.asarray(corner_uvs, np.float32).reshape(n_corners, 2)
        self._vbo_pos = ctx.buffer(reserve=n_corners * 12)
        self._vbo_nrm = ctx.buffer(reserve=n_corners * 12)
        self._vbo_uv = ctx.buffer(uvs.tobytes())
        self.vao = ctx.vertex_array(self.prog, [
            (self._vbo_pos, "3f", "in_position"),
            (self._vbo_nrm, "3f", "in_normal"),
            (self._vbo_uv, "2f", "in_uv"),
        ])
        self.texture = None
        if texture is not None:
            tex = np.ascontiguousarray(np.flipud(np.asarray(texture, np.uint8)[..., :3]))
            self.texture = ctx.texture((tex.shape[1], tex.shape[0]), 3, tex.tobytes())
            self.texture.build_mipmaps()
            self.texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self._fbo = None
        self._fbo_size = None

    def _framebuffer(self, w: int, h: int):
        if self._fbo_size != (w, h):
            if self._fbo is not None:
                self._fbo.release()
            self._fbo = self.ctx.framebuffer(
                color_attachments=[self.ctx.texture((w, h), 4, dtype="f4"), self.ctx.texture((w, h), 4, dtype="f4")],
                depth_attachment=self.ctx.depth_texture((w, h)),
            )
            self._fbo_size = (w, h)
        return self._fbo

    def render(self, vertices: np.ndarray, normals: np.ndarray, camera: Camera,
               background=(0.0, 0.0, 0.0), flat_color=(0.7, 0.7, 0.7)) -> MeshImages:
        s = self.supersample
        cam = camera.scaled(camera.width * s, camera.height * s)
        w, h = cam.width, cam.height
        corners = self.faces.reshape(-1)
        self._vbo_pos.write(np.asarray(vertices, np.float32)[corners].tobytes())
        self._vbo_nrm.write(np.asarray(normals, np.float32)[corners].tobytes())
        fbo = self._framebuffer(w, h)
        fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        self.prog["u_view"].write(cam.gl_view().T.astype(np.float32).tobytes())
        self.prog["u_proj"].write(cam.gl_projection().T.astype(np.float32).tobytes())
        self.prog["u_cam_rot"].write(cam.R.T.astype(np.float32).tobytes())  # column-major of R
        self.prog["u_ambient"].value = self.ambient
        self.prog["u_light_dir"].value = (0.0, 0.0, 1.0)
        self.prog["u_textured"].value = self.texture is not None
        self.prog["u_flat_color"].value = tuple(float(c) for c in flat_color)
        if self.texture is not None:
            self.texture.use(0)
            self.prog["u_texture"].value = 0
        self.vao.render(moderngl.TRIANGLES)
        color = self._read(fbo, 0, w, h)
        normal = self._read(fbo, 1, w, h)
        # GL rows start at the bottom; images start at the top
        color, normal = color[::-1], normal[::-1]
        cov = color[..., 3]
        rgb = color[..., :3]
        bg = np.asarray(background, np.float32)
        rgb_bg = rgb + (1.0 - cov[..., None]) * bg
        ds = lambda a: a.reshape(camera.height, s, camera.width, s, *a.shape[2:]).mean(axis=(1, 3))
        mask = ds(cov)
        n = ds(normal[..., :3])
        n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-8) * (mask[..., None] > 0)
        return MeshImages(ds(rgb_bg).astype(np.float32), mask.astype(np.float32), n.astype(np.float32))

    @staticmethod
    def _read(fbo, attachment: int, w: int, h: int) -> np.ndarray:
        data = fbo.read(components=4, attachment=attachment, dtype="f4")
        return np.frombuffer(data, np.float32).reshape(h, w, 4)

    def release(self) -> None:
        for obj in (self.vao, self._vbo_pos, self._vbo_nrm, self._vbo_uv, self.prog, self.texture, self._fbo):
            if obj is not None:
                obj.release()
