"""The front-leak ("tattoo") metric: how much of a FRONT-ONLY detail (the chest emblem, the face)
reappears on the back of a rendered avatar -- the failure of a back hallucinated by copying the
front.

Each unseen evaluation view of a synthetic scene carries a ``FrontLeakInfo``
(``EvalView.front_leak``): per front-only detail k, the region of the image where that detail would
land if the front were mirrored onto the back (the back of the torso behind the chest emblem, the
back of the head behind the face), as a coverage map in [0, 1] (the visible surface only), and the
detail's albedo colour(s). See reconstruct.data.synthetic.clothing.

Definition. A pixel x of region k, with rendered colour c(x) and ground-truth colour g(x), counts as
leaked when c(x) shows the detail's colour -- within TOLERANCE (0.15) of it -- and is closer to it
than to the ground truth there:

    leaked_k(x) = D_k(x) < min(|c(x) - g(x)|, TOLERANCE),   D_k(x) = min_j d(c(x), a_kj)

where a_kj are the detail's albedo colours and d(c, a) = min over s in [0.8, 1] of |c - s a| is the
RGB distance to the albedo under the scene's shading (the ground-truth renderer lights albedo with a
factor in [0.85, 1]). The score is the coverage-weighted share of leaked pixels over all regions:

    front_leak = sum_k sum_x w_k(x) leaked_k(x) / sum_k sum_x w_k(x)

It is exactly 0 for the ground truth (|g - g| = 0 is never beaten) and close to 1 for a back painted
with the mirrored front (each region pixel then shows the detail's shaded albedo, which is far from
the ground truth: regions leave out surface whose true colour is within 0.2 of the detail's). A
render that is simply wrong without resembling the detail (black, a flat average colour) scores
low: the tolerance keeps a colour that is merely nearer the detail than the truth from counting. Where no region is visible (sum of w below one pixel) the score is NaN: the view says
nothing about leaks; ``front_leak_mean`` skips such views.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

SHADE_RANGE = (0.8, 1.0)
TOLERANCE = 0.15  # RGB distance to a detail's (shaded) colour within which a pixel can show the detail
MIN_REGION_PIXELS = 1.0


@dataclass
class FrontLeakInfo:
    """What the front-leak metric needs of one evaluation view (besides its ground-truth image)."""

    names: tuple[str, ...]  # one per front-only detail, e.g. ("emblem", "face")
    regions: np.ndarray  # (H,W,K) float32 coverage in [0,1] of each detail's mirrored region
    colors: tuple[np.ndarray, ...]  # per detail, (n,3) float albedo colours in [0,1]

    def __post_init__(self) -> None:
        self.regions = np.asarray(self.regions, np.float32)
        if self.regions.ndim == 2:
            self.regions = self.regions[..., None]
        self.names = tuple(str(n) for n in self.names)
        self.colors = tuple(np.asarray(c, np.float64).reshape(-1, 3) for c in self.colors)
        K = self.regions.shape[-1]
        if len(self.names) != K or len(self.colors) != K:
            raise ValueError(f"front-leak info: {K} regions but {len(self.names)} names and {len(self.colors)} colour sets")

    def region_pixels(self) -> float:
        return float(self.regions.sum())


def _as_image(img, what: str) -> np.ndarray:
    if hasattr(img, "detach"):
        img = img.detach().cpu().numpy()
    img = np.asarray(img, np.float64)
    if img.ndim != 3 or img.shape[-1] < 3:
        raise ValueError(f"front_leak: {what} must be an (H, W, 3) image, found shape {img.shape}")
    return img[..., :3]


def shaded_distance(c: np.ndarray, albedo: np.ndarray, shade=SHADE_RANGE) -> np.ndarray:
    """Distance of colours ``c`` (...,3) to the albedo (3,) lit by the best factor in ``shade``."""
    a = np.asarray(albedo, np.float64)
    s = np.clip((c @ a) / max(float(a @ a), 1e-12), *shade)
    return np.linalg.norm(c - s[..., None] * a, axis=-1)


def front_leak(rendered_rgb, view_leak_info, reference_rgb=None) -> float:
    """The share of the front-only details' back regions that the render paints in the details'
    colours (see the module docstring). ``view_leak_info``: an EvalView with ``front_leak`` set (its
    ground-truth image is the reference), or a FrontLeakInfo together with ``reference_rgb``.
    NaN when no region is visible in the view."""
    info = view_leak_info
    if not isinstance(info, FrontLeakInfo):
        view = info
        info = getattr(view, "front_leak", None)
        if info is None:
            raise ValueError("front_leak: this evaluation view has no front-leak information (only the unseen "
                             "views of synthetic scenes have it)")
        if reference_rgb is None:
            reference_rgb = view.image
    if reference_rgb is None:
        raise ValueError("front_leak: the ground-truth image of the view is needed (reference_rgb)")
    c = _as_image(rendered_rgb, "the render")
    g = _as_image(reference_rgb, "the reference")
    H, W = info.regions.shape[:2]
    if c.shape[:2] != (H, W) or g.shape[:2] != (H, W):
        raise ValueError(f"front_leak: render {c.shape[:2]} and reference {g.shape[:2]} must be {(H, W)} like the regions")
    total = info.region_pixels()
    if total < MIN_REGION_PIXELS:
        return float("nan")
    d_truth = np.linalg.norm(c - g, axis=-1)
    leaked = 0.0
    for k, colors in enumerate(info.colors):
        w = info.regions[..., k]
        sel = w > 0
        if not sel.any():
            continue
        cs = c[sel]
        d_detail = np.min([shaded_distance(cs, a) for a in colors], axis=0)
        leaked += float((w[sel] * ((d_detail < d_truth[sel]) & (d_detail < TOLERANCE))).sum())
    return leaked / total


def front_leak_mean(renders: Sequence, views: Sequence) -> float:
    """Region-size-weighted mean of ``front_leak`` over the views that have front-leak information
    and a visible region (NaN when none has)."""
    num = den = 0.0
    for img, v in zip(renders, views):
        info = getattr(v, "front_leak", None)
        if info is None or info.region_pixels() < MIN_REGION_PIXELS:
            continue
        score = front_leak(img, v)
        num += score * info.region_pixels()
        den += info.region_pixels()
    return num / den if den > 0 else float("nan")
