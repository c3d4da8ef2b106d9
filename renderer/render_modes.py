"""What a splat image shows, and the colour code of each mode.

Every mode composites one colour per Gaussian with the same weights as the RGB image
(``w_i = alpha_i * prod_{j in front} (1 - alpha_j)``), so a mode's image is
``sum_i w_i c_i + (1 - A) * background`` with ``A = sum_i w_i`` the accumulated alpha.
The per-Gaussian colour ``c_i`` is:

RGB
    the Gaussian's colour (``Snapshot.colors``).
NORMAL
    ``c = 0.5 * (n_cam + 1)`` with ``n_cam = R @ n_world`` the unit normal in *OpenCV camera
    axes* of the viewing camera (x right, y down, z forward, away from the viewer; see
    ``reconstruct/camera.py``). So a normal pointing to the image's right is reddish
    (1, .5, .5), one pointing down is greenish (.5, 1, .5), one facing the camera (n_cam = -z)
    is (.5, .5, 0) (olive) and one facing away is (.5, .5, 1). Normals are not renormalised
    by blending: the composited value is the weighted mean colour. A Gaussian whose normal is
    non-finite or zero gets (.5, .5, .5).
DEPTH
    ``c = clip((far - z) / (far - near), 0, 1)`` in gray, ``z`` the camera depth of the
    Gaussian's mean and ``(near, far)`` the render's ``depth_range`` (by default the min and
    max depth of the Gaussians drawn in that frame): near is white, far is black. Because the
    map is affine, the composited gray equals the map of the alpha-normalised expected depth
    (``sum w_i z_i / A``), times ``A``, over the background.
ALPHA
    white per Gaussian composited over black, i.e. the image is ``A`` in gray; the background
    colour is ignored in this mode.
VISIBILITY
    the paper's Fig. 4 colour code: Gaussians seen in Stage I (``Snapshot.visibility == 1``,
    first hits on a training ray) in orange ``RGB(236,166,128)``, unseen ones in blue
    ``RGB(39,131,177)``.

The returned images carry the accumulated alpha ``A`` in their fourth channel in every mode.

Highlight (the studio's edit selection, ``Snapshot.highlight``: 1 on selected rows)
    in every mode a highlighted Gaussian's colour is mixed towards a bright orange
    (``HIGHLIGHT_RGB``, weight ``HIGHLIGHT_MIX``) -- towards yellow in the visibility mode, whose
    seen colour is orange already, and magenta in the normals mode, whose camera-facing normals are
    reds, yellows and greens (``RenderMode.highlight_rgb``). No highlight array: no tint.
"""

from __future__ import annotations

from enum import Enum

import numpy as np

SEEN_RGB8 = (236, 166, 128)
UNSEEN_RGB8 = (39, 131, 177)
SEEN_RGB = tuple(c / 255.0 for c in SEEN_RGB8)
UNSEEN_RGB = tuple(c / 255.0 for c in UNSEEN_RGB8)
BAD_NORMAL_RGB = (0.5, 0.5, 0.5)
HIGHLIGHT_RGB = (1.0, 0.45, 0.0)  # selected Gaussians are mixed towards this (bright orange)
HIGHLIGHT_VISIBILITY_RGB = (1.0, 0.95, 0.1)  # ... towards this in the visibility mode (yellow)
HIGHLIGHT_NORMAL_RGB = (1.0, 0.1, 1.0)  # ... and this in the normals mode (magenta)
HIGHLIGHT_MIX = 0.65


class RenderMode(str, Enum):
    RGB = "rgb"
    NORMAL = "normal"
    DEPTH = "depth"
    ALPHA = "alpha"
    VISIBILITY = "visibility"

    @classmethod
    def parse(cls, value: "RenderMode | str") -> "RenderMode":
        if isinstance(value, RenderMode):
            return value
        try:
            return cls(str(value).lower())
        except ValueError:
            raise ValueError(f"unknown render mode {value!r}; choose one of {[m.value for m in cls]}") from None

    @property
    def highlight_rgb(self) -> tuple[float, float, float]:
        """The colour highlighted (selected) Gaussians are mixed towards in this mode."""
        return {RenderMode.VISIBILITY: HIGHLIGHT_VISIBILITY_RGB, RenderMode.NORMAL: HIGHLIGHT_NORMAL_RGB}.get(
            self, HIGHLIGHT_RGB)

    @property
    def label(self) -> str:
        return {"rgb": "RGB", "normal": "Normals", "depth": "Depth", "alpha": "Alpha",
                "visibility": "Visibility (seen / unseen)"}[self.value]


# integer codes shared with shaders/splat.vert (u_mode)
SHADER_CODE = {
    RenderMode.RGB: 0,
    RenderMode.NORMAL: 1,
    RenderMode.DEPTH: 2,
    RenderMode.ALPHA: 3,
    RenderMode.VISIBILITY: 4,
}
SHADER_DEPTH_RAW = 5  # internal: colour = camera depth z (for render_depth)


def splat_colors(
    mode: RenderMode | str,
    *,
    R: np.ndarray,
    t: np.ndarray,
    means: np.ndarray,
    colors: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    visibility: np.ndarray | None = None,
    depth_range: tuple[float, float] = (0.0, 1.0),
    highlight: np.ndarray | None = None,
) -> np.ndarray:
    """Per-Gaussian colour (N,3) float64 of ``mode`` for a camera with world-to-camera ``R, t``;
    ``highlight`` ((N,) nonzero = selected) mixes the selected ones towards ``mode.highlight_rgb``.

    This is the CPU definition of the colour code; the vertex shader implements the same."""
    mode = RenderMode.parse(mode)
    out = _mode_colors(mode, R=R, t=t, means=means, colors=colors, normals=normals, visibility=visibility,
                       depth_range=depth_range)
    if highlight is None:
        return out
    sel = np.asarray(highlight).reshape(out.shape[0]) != 0
    tint = (1.0 - HIGHLIGHT_MIX) * out + HIGHLIGHT_MIX * np.asarray(mode.highlight_rgb, np.float64)
    return np.where(sel[:, None], tint, out)


def _mode_colors(mode: RenderMode, *, R, t, means, colors, normals, visibility, depth_range) -> np.ndarray:
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    means = np.asarray(means, np.float64)
    n = means.shape[0]
    if mode is RenderMode.RGB:
        return np.asarray(colors, np.float64).reshape(n, 3)
    if mode is RenderMode.NORMAL:
        nw = np.asarray(normals, np.float64).reshape(n, 3)
        ok = np.all(np.isfinite(nw), axis=1)
        nw = np.where(ok[:, None], nw, 0.0)
        length = np.linalg.norm(nw, axis=1, keepdims=True)
        good = (length[:, 0] > 1e-12)
        nc = (nw / np.where(good[:, None], length, 1.0)) @ R.T
        out = 0.5 * (nc + 1.0)
        out[~good] = BAD_NORMAL_RGB
        return out
    if mode is RenderMode.DEPTH:
        z = means @ R[2] + t[2]
        near, far = float(depth_range[0]), float(depth_range[1])
        span = far - near if far != near else 1e-12
        g = np.clip((far - z) / span, 0.0, 1.0)
        return np.repeat(g[:, None], 3, axis=1)
    if mode is RenderMode.ALPHA:
        return np.ones((n, 3))
    vis = np.asarray(visibility).reshape(n) != 0
    return np.where(vis[:, None], np.array(SEEN_RGB), np.array(UNSEEN_RGB))
