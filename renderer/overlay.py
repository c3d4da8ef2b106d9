"""Body mesh (wireframe or solid) and skeleton drawn over a splat image.

The overlay is drawn after the splats into the same framebuffer, with straight alpha blending
``(SRC_ALPHA, ONE_MINUS_SRC_ALPHA)`` on colour and ``(ONE, ONE_MINUS_SRC_ALPHA)`` on the alpha
channel. The mesh is depth tested against itself (hidden surfaces and, for the wireframe, hidden
edges removed through a depth pre-pass) but not against the splats, which write no depth: it is
an X-ray view on top of the avatar. Skeleton bones are screen-space quads ``line_width`` pixels
wide (a geometry shader; core GL only guarantees 1-pixel lines) and joints round points; they are
drawn last without depth test.

Positions go through ``Camera.gl_projection() @ Camera.gl_view()``, the same pixel mapping as
the splats (pixel centres at +0.5, v down).
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

import shaders
from reconstruct.camera import Camera


@dataclass
class OverlayStyle:
    mesh: str | None = "wireframe"  # None, "wireframe" or "solid"
    mesh_color: tuple = (0.85, 0.85, 0.85, 0.6)  # RGBA, straight alpha
    skeleton: bool = True
    bone_color: tuple = (1.0, 0.25, 0.2, 1.0)
    joint_color: tuple = (1.0, 0.95, 0.3, 1.0)
    line_width: float = 2.0  # pixels, skeleton bones
    joint_size: float = 6.0  # pixels, joint dots

    def __post_init__(self) -> None:
        if self.mesh not in (None, "wireframe", "solid"):
            raise ValueError(f"OverlayStyle.mesh must be None, 'wireframe' or 'solid', found {self.mesh!r}")


def gl_matrices(camera: Camera) -> tuple[bytes, bytes]:
    """(mvp, view) as column-major float32 bytes for GLSL mat4 uniforms."""
    view = camera.gl_view()
    mvp = camera.gl_projection() @ view
    return (np.ascontiguousarray(mvp.T, np.float32).tobytes(), np.ascontiguousarray(view.T, np.float32).tobytes())


class OverlayRenderer:
    """Holds the mesh and skeleton buffers of one context; re-uploads only on ``set_*``."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        vert = shaders.load("overlay.vert")
        frag = shaders.load("overlay.frag")
        geom_vert = vert.replace("#version 330 core", "#version 330 core\n#define FOR_GEOMETRY", 1)
        self.prog = ctx.program(vertex_shader=vert, fragment_shader=frag)
        self.line_prog = ctx.program(vertex_shader=geom_vert, geometry_shader=shaders.load("overlay.geom"),
                                     fragment_shader=frag)
        self._mesh = None  # (vbo, ibo, vao, n_indices)
        self._bones = None  # (vbo, vao_lines, vao_points, n_bone_vertices, n_joints)
        self.mesh_faces_dropped = 0
        self.joints_dropped = 0

    # ----- data ------------------------------------------------------------------------------
    def set_mesh(self, vertices: np.ndarray | None, faces: np.ndarray | None) -> None:
        self._free_mesh()
        self.mesh_faces_dropped = 0
        if vertices is None or faces is None:
            return
        v = np.asarray(vertices, np.float32).reshape(-1, 3)
        f = np.asarray(faces).reshape(-1, 3)
        if v.shape[0] == 0 or f.shape[0] == 0:
            return
        f = f.astype(np.int64)
        ok = np.all((f >= 0) & (f < v.shape[0]), axis=1)
        finite_v = np.all(np.isfinite(v), axis=1)
        ok[ok] &= np.all(finite_v[f[ok]], axis=1)
        self.mesh_faces_dropped = int((~ok).sum())
        f = f[ok].astype(np.uint32)
        if f.shape[0] == 0:
            return
        v = np.where(finite_v[:, None], v, 0.0).astype(np.float32)
        vbo = self.ctx.buffer(v.tobytes())
        ibo = self.ctx.buffer(f.tobytes())
        vao = self.ctx.vertex_array(self.prog, [(vbo, "3f", "in_pos")], index_buffer=ibo, index_element_size=4)
        self._mesh = (vbo, ibo, vao, int(f.size))

    def set_skeleton(self, joints: np.ndarray | None, parents: np.ndarray | None) -> None:
        self._free_bones()
        self.joints_dropped = 0
        if joints is None:
            return
        j = np.asarray(joints, np.float32).reshape(-1, 3)
        if j.shape[0] == 0:
            return
        finite = np.all(np.isfinite(j), axis=1)
        self.joints_dropped = int((~finite).sum())
        segs = []
        if parents is not None:
            p = np.asarray(parents).reshape(-1).astype(np.int64)
            if p.shape[0] != j.shape[0]:
                raise ValueError(f"joint_parents has {p.shape[0]} entries for {j.shape[0]} joints")
            child = np.arange(j.shape[0])
            ok = (p >= 0) & (p < j.shape[0]) & finite
            ok[ok] &= finite[p[ok]]
            segs = np.stack([j[p[ok]], j[child[ok]]], axis=1).reshape(-1, 3)
        pts = j[finite]
        data = np.concatenate([np.asarray(segs, np.float32).reshape(-1, 3), pts], axis=0).astype(np.float32)
        if data.shape[0] == 0:
            return
        vbo = self.ctx.buffer(data.tobytes())
        vao_lines = self.ctx.vertex_array(self.line_prog, [(vbo, "3f", "in_pos")])
        vao_points = self.ctx.vertex_array(self.prog, [(vbo, "3f", "in_pos")])
        n_seg_vertices = int(len(segs)) if len(segs) else 0
        self._bones = (vbo, vao_lines, vao_points, n_seg_vertices, int(pts.shape[0]))

    @property
    def has_mesh(self) -> bool:
        return self._mesh is not None

    @property
    def has_skeleton(self) -> bool:
        return self._bones is not None

    # ----- drawing ---------------------------------------------------------------------------
    def render(self, camera: Camera, fbo: moderngl.Framebuffer, style: OverlayStyle) -> None:
        """Draw into ``fbo`` (already bound, viewport set) for ``camera``."""
        ctx = self.ctx
        mvp, view = gl_matrices(camera)
        for prog in (self.prog, self.line_prog):
            prog["u_mvp"].write(mvp)
            if "u_view" in prog:
                prog["u_view"].write(view)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = (moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA, moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA)
        if self._mesh is not None and style.mesh is not None:
            _, _, vao, _ = self._mesh
            self._clear_depth(fbo)
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.depth_func = "<="
            if style.mesh == "wireframe":
                # depth pre-pass of the filled mesh, pushed back, so that hidden edges fail
                # (a fully transparent colour with blending leaves the colour unchanged)
                ctx.polygon_offset = (1.0, 1.0)
                self._set(self.prog, color=(0, 0, 0, 0), shading=0)
                ctx.blend_func = (moderngl.ZERO, moderngl.ONE)
                vao.render(moderngl.TRIANGLES)
                ctx.blend_func = (moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA, moderngl.ONE,
                                  moderngl.ONE_MINUS_SRC_ALPHA)
                ctx.polygon_offset = (0.0, 0.0)
                ctx.wireframe = True
                self._set(self.prog, color=style.mesh_color, shading=0)
                vao.render(moderngl.TRIANGLES)
                ctx.wireframe = False
            else:
                self._set(self.prog, color=style.mesh_color, shading=1)
                vao.render(moderngl.TRIANGLES)
            ctx.disable(moderngl.DEPTH_TEST)
        if self._bones is not None and style.skeleton:
            _, vao_lines, vao_points, n_seg, n_pts = self._bones
            if n_seg:
                self.line_prog["u_size"].value = (float(camera.width), float(camera.height))
                self.line_prog["u_line_width"].value = float(style.line_width)
                self._set(self.line_prog, color=style.bone_color, shading=0)
                vao_lines.render(moderngl.LINES, vertices=n_seg)
            if n_pts:
                ctx.enable(moderngl.PROGRAM_POINT_SIZE)
                self.prog["u_point_size"].value = float(style.joint_size)
                self._set(self.prog, color=style.joint_color, shading=2)
                vao_points.render(moderngl.POINTS, vertices=n_pts, first=n_seg)
                ctx.disable(moderngl.PROGRAM_POINT_SIZE)
                self.prog["u_point_size"].value = 1.0

    @staticmethod
    def _set(prog, color, shading) -> None:
        prog["u_color"].value = tuple(float(c) for c in color)
        if "u_shading" in prog:
            prog["u_shading"].value = int(shading)

    def _clear_depth(self, fbo: moderngl.Framebuffer) -> None:
        viewport = self.ctx.viewport
        old = fbo.color_mask
        fbo.color_mask = (False, False, False, False)
        fbo.clear(depth=1.0, viewport=viewport)
        fbo.color_mask = old
        fbo.use()  # re-applies the colour mask in GL (moderngl sets it when binding) ...
        self.ctx.viewport = viewport  # ... and resets the viewport

    # ----- lifetime ---------------------------------------------------------------------------
    def _free_mesh(self) -> None:
        if self._mesh is not None:
            vbo, ibo, vao, _ = self._mesh
            for o in (vao, ibo, vbo):
                o.release()
        self._mesh = None

    def _free_bones(self) -> None:
        if self._bones is not None:
            vbo, vl, vp, _, _ = self._bones
            for o in (vl, vp, vbo):
                o.release()
        self._bones = None

    def release(self) -> None:
        self._free_mesh()
        self._free_bones()
        for prog in (self.prog, self.line_prog):
            prog.release()
