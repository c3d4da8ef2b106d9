"""3D Gaussian splats (one screen-space quad per Gaussian) over a moderngl context: EGL offscreen
or a window's.

Pipeline per frame
------------------
1. ``set_snapshot(snap)`` (cheap when nothing changed): when the snapshot is a new object or its
   ``version`` changed, the arrays are sanitized once on the CPU and packed into one float32
   texture (5 RGBA texels per Gaussian: mean+opacity, scale+visibility, quaternion wxyz,
   colour, normal), uploaded with one write. Nothing else is uploaded per snapshot.
2. ``render(camera, ...)``: camera depth of each Gaussian, culling of Gaussians at or behind
   the near plane, beyond the far plane, or whose 3σ extent along the viewing direction reaches
   the near plane, and a back-to-front radix sort on a 16-bit depth key (``renderer.sorting``).
   This step is skipped (and nothing is uploaded) while the data version and the camera's depth
   row (R[2], t[2]) stay the same. The sorted ids go up as a uint32 element buffer (4 bytes per
   splat per sort).
3. One draw of ``n`` points through that element buffer, so the vertex shader runs once per
   Gaussian with ``gl_VertexID`` = its id: it fetches the Gaussian, builds the 3D covariance from
   scale and quaternion and projects it like the training rasterizer (pinhole K, OpenCV axes,
   Jacobian with x/z and y/z clamped to 1.3x the half-FOV tangent, + 0.3 px² low-pass); the
   geometry shader emits one quad covering the ellipse where ``o·exp(-½ dᵀΣ⁻¹d) ≥ 1/255``
   clipped to the rasterizer's box, ±ceil(3 sqrt(λ_max)) pixels on both axes (``box="axes"``:
   ±3σ per axis) — the smaller of the axis-aligned and the oriented rectangle. (On llvmpipe a
   point + geometry shader draw measured ~10-25 % faster than instanced quads: the vertex work
   runs once per splat instead of four times, and oriented quads cut fragments of thin splats.)
   The fragment shader keeps pixels inside the box, evaluates
   ``alpha = min(0.99, o·exp(-½ dᵀΣ⁻¹d))``, drops alpha < 1/255 and writes premultiplied colour;
   blending is ``(ONE, ONE_MINUS_SRC_ALPHA)`` on all four channels over a clear colour
   ``(background, 0)``. The result equals the rasterizer's front-to-back sum
   ``sum_i c_i a_i T_i + T_N · background`` and its alpha channel is ``1 - T_N`` (the
   rasterizer's stop once T < 1e-4 is not reproduced: it changes at most ~1e-2 of alpha behind
   two saturated layers).

Differences from the training rasterizer by design: Gaussians whose mean is beyond
``camera.far`` or whose 3σ extent along the view reaches the near plane are skipped (the
rasterizer keeps them; the latter would blow up into screen-filling blobs in a viewer), and
depth order uses a 16-bit key (ties within (zmax - zmin)/65535 keep index order).
4. Optional overlay (mesh / skeleton), then readback (offscreen) or nothing (window).

Highlight (the studio's edit selection): ``Snapshot.highlight`` ((N,) uint8, 1 = selected) goes up as
one float vertex attribute per Gaussian (4 bytes each), fetched by the element index like the data
texture; the ``u_highlight`` uniform switches the tint on (any row selected) or off (no array, or
nothing selected). A snapshot that differs from the current one only in ``highlight`` (the same
array objects and version, e.g. ``dataclasses.replace(snap, highlight=h)``) uploads only that
attribute (``stats.highlight_upload_ms``), so a brush stroke does not re-pack the Gaussians.
Selected Gaussians are mixed towards ``RenderMode.highlight_rgb`` in every mode (orange; yellow in
the visibility mode, magenta in the normals mode).

Offscreen images are (H, W, 4) float32 (or uint8), top row first. A float32 render target is
the default so that blending thousands of splats does not accumulate 8-bit rounding.

Bad input: rows with NaN/inf in means, scales, rotations, colours or opacities, negative scales,
all-zero scales or any scale > ``max_scale``, zero-norm quaternions and opacities that can never
reach 1/255 are dropped once per snapshot version and counted in ``stats.skipped`` by reason
(``nonfinite``, ``bad_scale``, ``bad_rotation``, ``transparent``); per frame the counts
``behind_camera``, ``near_plane`` and ``beyond_far`` are added. One or two zero scale axes (flat
discs, needles) are valid and drawn. Non-finite or zero normals only affect the normal mode
(gray) and are counted in ``stats.bad_normals``.

One renderer per context; call ``release()`` to free its GL objects.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import moderngl
import numpy as np

import shaders
from reconstruct.camera import Camera
from reconstruct.snapshot import Snapshot

from .framebuffer import OffscreenTarget
from .overlay import OverlayRenderer, OverlayStyle
from .render_modes import (
    HIGHLIGHT_MIX,
    SEEN_RGB,
    SHADER_CODE,
    SHADER_DEPTH_RAW,
    UNSEEN_RGB,
    RenderMode,
)
from .sorting import SortCache

TEXELS_PER_SPLAT = 5
SNAPSHOT_FIELDS = tuple(f.name for f in dataclasses.fields(Snapshot) if f.name != "highlight")
SKIP_REASONS = ("nonfinite", "bad_scale", "bad_rotation", "transparent", "behind_camera", "near_plane",
                "beyond_far", "overflow")


@dataclass
class RenderStats:
    """What the last ``set_snapshot`` / ``render`` did. Times in milliseconds."""

    n_input: int = 0  # Gaussians in the snapshot
    n_valid: int = 0  # after per-snapshot sanitizing (uploaded)
    n_drawn: int = 0  # splats sent to the GPU in the last frame (the vertex shader still drops
    #                   those whose box misses the image or whose 2D covariance is degenerate)
    skipped: dict = field(default_factory=lambda: {k: 0 for k in SKIP_REASONS})
    bad_normals: int = 0
    data_version: int = -1
    data_uploaded: bool = False  # the last render (or set_snapshot) uploaded the Gaussian data
    sorted: bool = False  # the last render sorted (view or data changed)
    data_upload_ms: float = 0.0  # sanitize + pack + texture write, when it happened
    n_highlighted: int = 0  # uploaded Gaussians with the highlight set (0: tint off)
    highlight_upload_ms: float = 0.0  # the last upload of the highlight attribute
    sort_ms: float = 0.0  # depth, culling and radix sort (0 when skipped)
    upload_ms: float = 0.0  # per-frame upload of the sorted ids (0 when skipped)
    draw_ms: float = 0.0  # issue + finish of the splat draw (finish only offscreen / profile)
    overlay_ms: float = 0.0
    readback_ms: float = 0.0
    total_ms: float = 0.0

    @property
    def skipped_total(self) -> int:
        return int(sum(self.skipped.values()))


class SplatRenderer:
    """Draws a ``Snapshot``'s Gaussians with moderngl; see the module docstring."""

    def __init__(
        self,
        ctx: moderngl.Context,
        *,
        target_dtype: str = "f4",
        sort_bits: int = 16,
        eps2d: float = 0.3,
        box_sigma: float = 3.0,
        box: str = "square",
        alpha_min: float = 1.0 / 255.0,
        alpha_max: float = 0.99,
        fov_clamp: float = 1.3,
        near_sigma: float = 3.0,
        max_scale: float = 1e3,
    ):
        self.ctx = ctx
        self.target_dtype = target_dtype
        self.eps2d = float(eps2d)
        self.box_sigma = float(box_sigma)
        if box not in ("square", "axes"):
            raise ValueError(f"box must be 'square' (the rasterizer's) or 'axes', found {box!r}")
        self.box = box
        self.alpha_min = float(alpha_min)
        self.alpha_max = float(alpha_max)
        self.fov_clamp = float(fov_clamp)
        self.max_scale = float(max_scale)
        self.prog = ctx.program(vertex_shader=shaders.load("splat.vert"), geometry_shader=shaders.load("splat.geom"),
                                fragment_shader=shaders.load("splat.frag"))
        self.sorter = SortCache(bits=sort_bits, near_sigma=near_sigma)
        self.stats = RenderStats()
        self.overlay: OverlayRenderer | None = None
        self._overlay_key = None
        self._target: OffscreenTarget | None = None
        self._tex: moderngl.Texture | None = None
        self._per_row = 1
        self._ids: moderngl.Buffer | None = None
        self._vao: moderngl.VertexArray | None = None
        self._hl_buf: moderngl.Buffer | None = None  # per-Gaussian highlight attribute (float32)
        self._hl_on = False
        self._rows: slice | np.ndarray = slice(None)  # snapshot rows kept by sanitizing, in upload order
        self._n_valid = 0
        self._snap: Snapshot | None = None
        self._snap_version = None
        self._data_key = 0  # increments on every data change (sort cache key)
        self._means_t = np.zeros((3, 0), np.float32)
        self._max_scale = np.zeros(0, np.float32)
        self._scales = np.zeros((0, 3), np.float32)
        self._quats = np.zeros((0, 4), np.float32)
        self._base_skipped = {k: 0 for k in SKIP_REASONS}
        self._uploaded_order = None
        self._max_tex = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 4096))
        self._per_row = max(1, min(2048, self._max_tex // TEXELS_PER_SPLAT))
        self.prog["u_data"].value = 0
        self._released = False

    # ------------------------------------------------------------------ data
    def set_snapshot(self, snap: Snapshot | None) -> bool:
        """Use ``snap`` for the next renders. Uploads (and returns True) only when it is a
        different snapshot object or its ``version`` changed."""
        if snap is None:
            snap = Snapshot.empty()
        if snap is self._snap and snap.version == self._snap_version:
            self.stats.data_uploaded = False
            return False
        if self._same_arrays(snap):  # only the highlight changed: upload that alone
            self._snap = snap
            self._set_highlight(snap.highlight)
            self.stats.data_uploaded = False
            return False
        t0 = time.perf_counter()
        storage, per_row, m, skipped, bad_normals, n_in, rows = self._sanitize(snap)
        self._upload(storage, per_row)
        packed = storage[:m]
        # CPU copies for culling and sorting (structure of arrays)
        self._means_t = np.ascontiguousarray(packed[:, 0, :3].T)
        self._scales = packed[:, 1, :3]
        self._max_scale = self._scales.max(axis=1) if packed.shape[0] else np.zeros(0, np.float32)
        self._quats = packed[:, 2, :]
        self._base_skipped = skipped
        self._snap, self._snap_version = snap, snap.version
        self._rows, self._n_valid = rows, m
        self._data_key += 1
        self._overlay_key = None  # mesh / skeleton re-upload on next overlay render
        st = self.stats
        st.n_input, st.n_valid, st.bad_normals = n_in, packed.shape[0], bad_normals
        st.data_version = int(snap.version)
        st.data_uploaded = True
        st.data_upload_ms = (time.perf_counter() - t0) * 1e3
        st.skipped = dict(skipped)
        self._set_highlight(snap.highlight)
        return True

    def _same_arrays(self, snap: Snapshot) -> bool:
        """``snap`` is the current snapshot but for ``highlight``: every other field the very same
        object (``dataclasses.replace(current, highlight=h)``)."""
        cur = self._snap
        return (cur is not None and snap.version == self._snap_version
                and all(getattr(snap, k) is getattr(cur, k) for k in SNAPSHOT_FIELDS))

    def _set_highlight(self, highlight) -> None:
        """The per-Gaussian highlight attribute of the current snapshot (None: tint off)."""
        t0 = time.perf_counter()
        st = self.stats
        n_in, m = st.n_input, self._n_valid
        if highlight is None or m == 0:
            self._hl_on = False
            st.n_highlighted = 0
            return
        h = np.asarray(highlight)
        if h.shape != (n_in,):
            raise ValueError(f"Snapshot.highlight: expected shape ({n_in},), found {h.shape}")
        flags = (h[self._rows] != 0).astype(np.float32)
        st.n_highlighted = int(np.count_nonzero(flags))
        self._hl_on = st.n_highlighted > 0
        if self._hl_on:
            self._ensure_highlight_buffer(m)
            self._hl_buf.write(flags.tobytes())
        st.highlight_upload_ms = (time.perf_counter() - t0) * 1e3

    def _ensure_highlight_buffer(self, m: int) -> None:
        """A highlight buffer for at least ``m`` Gaussians (the vertex array is rebuilt with it)."""
        nbytes = max(4 * m, 1024)
        if self._hl_buf is not None and self._hl_buf.size >= nbytes:
            return
        if self._vao is not None:
            self._vao.release()
            self._vao = None
        if self._hl_buf is not None:
            self._hl_buf.release()
        self._hl_buf = self.ctx.buffer(reserve=nbytes + nbytes // 4, dynamic=True)

    def _sanitize(self, snap: Snapshot):
        n = len(snap)

        def arr(name, cols, dtype=np.float32, required=True):
            a = getattr(snap, name)
            if a is None:
                if required:
                    raise ValueError(f"Snapshot.{name} is missing")
                return None
            a = np.asarray(a)
            want = (n,) if cols is None else (n, cols)
            if a.shape != want:
                if a.size == 0 and not required:
                    return None
                raise ValueError(f"Snapshot.{name}: expected shape {want}, found {a.shape}")
            return a.astype(dtype, copy=False)

        means = arr("means", 3)
        scales = arr("scales", 3)
        quats = arr("rotations", 4)
        colors = arr("colors", 3)
        opac = arr("opacities", None)
        normals = arr("normals", 3, required=False)
        vis = arr("visibility", None, dtype=np.float32, required=False)

        skipped = {k: 0 for k in SKIP_REASONS}
        with np.errstate(invalid="ignore", over="ignore"):
            finite = (np.isfinite(means).all(1) & np.isfinite(scales).all(1) & np.isfinite(quats).all(1)
                      & np.isfinite(colors).all(1) & np.isfinite(opac))
            good_scale = (scales >= 0).all(1) & (scales <= self.max_scale).all(1) & (scales > 0).any(1)
            qnorm = np.sqrt((quats.astype(np.float64) ** 2).sum(1))
            good_rot = qnorm > 1e-12
            visible = opac >= self.alpha_min
        keep = finite.copy()
        skipped["nonfinite"] = int((~finite).sum())
        bad = keep & ~good_scale
        skipped["bad_scale"] = int(bad.sum())
        keep &= good_scale
        bad = keep & ~good_rot
        skipped["bad_rotation"] = int(bad.sum())
        keep &= good_rot
        bad = keep & ~visible
        skipped["transparent"] = int(bad.sum())
        keep &= visible
        limit = self._per_row * self._max_tex
        if keep.all() and n <= limit:
            idx = slice(None)  # the common case: no gather copies
            m = n
        else:
            idx = np.flatnonzero(keep)
            if idx.size > limit:
                skipped["overflow"] = int(idx.size - limit)
                idx = idx[:limit]
            m = idx.size

        # rows padded to whole texture rows so the buffer uploads without another copy
        per_row = self._per_row if m >= self._per_row else max(1, m)
        rows = max(1, -(-m // per_row))
        storage = np.zeros((rows * per_row, TEXELS_PER_SPLAT, 4), np.float32)
        packed = storage[:m]
        packed[:, 0, :3] = means[idx]
        packed[:, 0, 3] = opac[idx]
        packed[:, 1, :3] = scales[idx]
        packed[:, 1, 3] = 0.0 if vis is None else (vis[idx] != 0)
        packed[:, 2, :] = quats[idx] / qnorm[idx, None]
        packed[:, 3, :3] = colors[idx]
        bad_normals = 0
        if normals is not None:
            nn = normals[idx]
            with np.errstate(invalid="ignore"):
                okn = np.isfinite(nn).all(1) & (np.abs(nn).sum(1) > 0)
            bad_normals = int((~okn).sum())
            packed[:, 4, :3] = np.where(okn[:, None], nn, 0.0)
        else:
            bad_normals = m

        return storage, per_row, m, skipped, bad_normals, n, idx

    def _upload(self, storage: np.ndarray, per_row: int) -> None:
        """One texture write of ``storage`` ((rows * per_row, 5, 4) float32)."""
        width = per_row * TEXELS_PER_SPLAT
        rows = storage.shape[0] // per_row
        if self._tex is None or self._tex.size != (width, rows):
            if self._tex is not None:
                self._tex.release()
            self._tex = self.ctx.texture((width, rows), 4, dtype="f4")
            self._tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._tex.repeat_x = self._tex.repeat_y = False
        self._tex.write(memoryview(storage.reshape(-1)))
        self.prog["u_per_row"].value = per_row
        self._uploaded_order = None

    # ------------------------------------------------------------------ drawing
    def render(
        self,
        camera: Camera,
        mode: RenderMode | str = RenderMode.RGB,
        background=(0.0, 0.0, 0.0),
        target: moderngl.Framebuffer | None = None,
        *,
        depth_range: tuple[float, float] | None = None,
        overlay: OverlayStyle | None = None,
        dtype=np.float32,
        clear: bool = True,
        finish: bool | None = None,
    ) -> np.ndarray | None:
        """Draw the current snapshot as seen by ``camera``.

        ``target=None``: render offscreen into a float framebuffer of the camera's size and return
        the image (H, W, 4), top row first, ``dtype`` float32 or uint8; rgb is composited over
        ``background`` (RGB in [0,1]; ``None`` = transparent black, i.e. premultiplied colour),
        the fourth channel is the accumulated alpha. With a ``target`` framebuffer (e.g. the
        window's ``ctx.screen``) it draws into it with viewport (0, 0, camera.width,
        camera.height), clears it first if ``clear``, and returns None. ``depth_range`` (near,
        far) for the depth mode; default the drawn splats' depth range. ``overlay`` draws the
        snapshot's mesh / skeleton on top. ``finish`` waits for the GPU after the draw so that
        ``stats.draw_ms`` is the real draw time (default: when rendering offscreen).
        """
        if self._released:
            raise RuntimeError("SplatRenderer was released")
        mode = RenderMode.parse(mode)
        return self._render(camera, SHADER_CODE[mode], mode is RenderMode.ALPHA, background, target,
                            depth_range, overlay, dtype, clear, finish)

    def render_depth(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """Accumulated camera depth ``sum_i w_i z_i`` (H, W) and alpha ``sum_i w_i`` (H, W),
        float32; ``depth / alpha`` is the training rasterizer's (expected) ``depth``. Needs the
        default float32 offscreen target."""
        if self.target_dtype != "f4":
            raise ValueError(f"render_depth needs target_dtype='f4', this renderer uses {self.target_dtype!r}")
        img = self._render(camera, SHADER_DEPTH_RAW, True, None, None, None, None, np.float32, True, None)
        return img[..., 0].copy(), img[..., 3].copy()

    def _render(self, camera, code, ignore_bg, background, target, depth_range, overlay, dtype, clear, finish):
        ctx = self.ctx
        st = self.stats
        t_start = time.perf_counter()
        if self._snap is None:
            self.set_snapshot(Snapshot.empty())
        W, H = camera.width, camera.height

        # ---- cull + sort (only when the view or the data changed)
        t0 = time.perf_counter()
        res, did_sort = self.sorter.get(self._data_key, self._means_t, self._max_scale, self._quats, self._scales,
                                        camera.R, camera.t, camera.near, camera.far)
        st.sorted = did_sort
        st.sort_ms = (time.perf_counter() - t0) * 1e3 if did_sort else 0.0
        st.skipped = dict(self._base_skipped)
        st.skipped["behind_camera"] = res.behind_camera
        st.skipped["near_plane"] = res.near_plane
        st.skipped["beyond_far"] = res.beyond_far

        # ---- per-frame upload of the order
        t0 = time.perf_counter()
        n = int(res.order.shape[0])
        uploaded = False
        if n and self._uploaded_order is not res.order:
            nbytes = n * 4
            if self._ids is None or self._ids.size < nbytes:
                if self._vao is not None:
                    self._vao.release()
                    self._vao = None
                if self._ids is not None:
                    self._ids.release()
                self._ids = ctx.buffer(reserve=max(nbytes + nbytes // 4, 1024), dynamic=True)
            self._ids.write(res.order.tobytes())
            self._uploaded_order = res.order
            uploaded = True
        if n:
            self._ensure_highlight_buffer(self._n_valid)
            if self._vao is None:
                self._vao = ctx.vertex_array(self.prog, [(self._hl_buf, "f4", "a_highlight")], index_buffer=self._ids,
                                             index_element_size=4)
        st.upload_ms = (time.perf_counter() - t0) * 1e3 if uploaded else 0.0
        st.n_drawn = n

        # ---- target
        if target is None:
            if self._target is None:
                self._target = OffscreenTarget(ctx, W, H, dtype=self.target_dtype, depth=True)
            else:
                self._target.resize(W, H)
            fbo = self._target.fbo
            if finish is None:
                finish = True
        else:
            fbo = target
        fbo.use()
        ctx.viewport = (0, 0, W, H)
        bg = (0.0, 0.0, 0.0) if (background is None or ignore_bg) else tuple(float(c) for c in background)[:3]
        if clear:
            fbo.clear(bg[0], bg[1], bg[2], 0.0, depth=1.0, viewport=(0, 0, W, H))

        # ---- draw
        t0 = time.perf_counter()
        if n:
            self._set_uniforms(camera, code, depth_range, res)
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = (moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA)
            ctx.blend_equation = moderngl.FUNC_ADD
            self._tex.use(location=0)
            self._vao.render(moderngl.POINTS, vertices=n)
        if finish:
            ctx.finish()
        st.draw_ms = (time.perf_counter() - t0) * 1e3

        # ---- overlay
        t0 = time.perf_counter()
        if overlay is not None:
            self._draw_overlay(camera, fbo, overlay)
            if finish:
                ctx.finish()
        st.overlay_ms = (time.perf_counter() - t0) * 1e3 if overlay is not None else 0.0

        out = None
        t0 = time.perf_counter()
        if target is None:
            out = self._target.read(dtype)
        st.readback_ms = (time.perf_counter() - t0) * 1e3 if target is None else 0.0
        st.total_ms = (time.perf_counter() - t_start) * 1e3
        return out

    def _set_uniforms(self, camera: Camera, code: int, depth_range, res) -> None:
        p = self.prog
        p["u_R"].write(np.ascontiguousarray(camera.R.T, np.float32).tobytes())  # column-major
        p["u_t"].value = tuple(float(v) for v in camera.t)
        p["u_K"].value = (camera.fx, camera.fy, camera.cx, camera.cy)
        W, H = camera.width, camera.height
        p["u_size"].value = (float(W), float(H))
        # gsplat / 3DGS: x/z clamped to [-(cx/fx + 0.3 tan_fovx), (W - cx)/fx + 0.3 tan_fovx]
        # (= +-1.3 tan_fovx for a centred camera), likewise y
        extra = self.fov_clamp - 1.0
        tan_x = 0.5 * W / camera.fx
        tan_y = 0.5 * H / camera.fy
        p["u_lim"].value = (camera.cx / camera.fx + extra * tan_x, (W - camera.cx) / camera.fx + extra * tan_x,
                            camera.cy / camera.fy + extra * tan_y, (H - camera.cy) / camera.fy + extra * tan_y)
        p["u_near"].value = float(camera.near)
        p["u_far"].value = float(camera.far)
        p["u_eps2d"].value = self.eps2d
        p["u_box_sigma"].value = self.box_sigma
        p["u_box_square"].value = 1 if self.box == "square" else 0
        p["u_alpha_min"].value = self.alpha_min
        p["u_alpha_max"].value = self.alpha_max
        p["u_mode"].value = int(code)
        if depth_range is None:
            depth_range = (res.depth_min, res.depth_max)
        p["u_depth_range"].value = (float(depth_range[0]), float(depth_range[1]))
        p["u_seen"].value = SEEN_RGB
        p["u_unseen"].value = UNSEEN_RGB
        p["u_highlight"].value = 1 if self._hl_on else 0
        hl_mode = next((m for m, c in SHADER_CODE.items() if c == code), RenderMode.RGB)
        p["u_highlight_rgb"].value = hl_mode.highlight_rgb
        p["u_highlight_mix"].value = HIGHLIGHT_MIX

    def _draw_overlay(self, camera: Camera, fbo, style: OverlayStyle) -> None:
        if self.overlay is None:
            self.overlay = OverlayRenderer(self.ctx)
        key = (self._data_key,)
        if self._overlay_key != key:
            snap = self._snap
            self.overlay.set_mesh(getattr(snap, "mesh_vertices", None), getattr(snap, "mesh_faces", None))
            self.overlay.set_skeleton(getattr(snap, "joints", None), getattr(snap, "joint_parents", None))
            self._overlay_key = key
        self.overlay.render(camera, fbo, style)

    # ------------------------------------------------------------------ lifetime
    @property
    def snapshot(self) -> Snapshot | None:
        return self._snap

    def release(self) -> None:
        if self._released:
            return
        for obj in (self._vao, self._ids, self._hl_buf, self._tex, self.prog):
            if obj is not None:
                obj.release()
        if self._target is not None:
            self._target.release()
        if self.overlay is not None:
            self.overlay.release()
        self._vao = self._ids = self._hl_buf = self._tex = None
        self._target = None
        self.overlay = None
        self._released = True

    def __enter__(self) -> "SplatRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()
