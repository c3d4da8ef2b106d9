"""Person masks worth training on: fill holes a body and its clothes cannot have, remove other people.

A hole is a background region enclosed by the person. Small ones (below ``max_hole`` of the person's
area) are segmenter mistakes and are filled; larger ones are real (a hand on the hip, the gap between
arm and body) and are kept. Given the image, a small hole whose pixels look more like the background
near it than like the person round it is real too (a narrow gap between an arm and the body in front
of a cluttered wall) and is kept. The GrabCut refinement itself runs with the detector
(``grabcut_refine.py``).
"""

from __future__ import annotations

import numpy as np

MAX_HOLE = 0.01  # holes up to 1 % of the person's area are filled
# a small hole is background when more than this share of its pixels are nearer in colour to the
# background within ``BACKGROUND_REACH`` of it than to the person within ``PERSON_RING`` px round it
BACKGROUND_SHARE = 0.5
BACKGROUND_REACH = 0.1  # of the person's height
PERSON_RING = 3  # px
_SAMPLE = 4000  # colours compared at most, per side


def hole_is_background(image: np.ndarray, person: np.ndarray, hole: np.ndarray, *,
                       reach: float, ring: int = PERSON_RING, share: float = BACKGROUND_SHARE) -> bool:
    """Whether the pixels of ``hole`` ((H,W) bool) in ``image`` ((H,W,3)) are mostly nearer in colour
    to the background (not ``person``, not the hole) within ``reach`` px of the hole than to the
    person within ``ring`` px round it: more than ``share`` of them. False when either side has
    fewer than 8 pixels."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    around = ndimage.binary_dilation(hole, iterations=ring) & person
    near = (ndimage.distance_transform_edt(~hole) <= reach) & ~person & ~hole
    if around.sum() < 8 or near.sum() < 8:
        return False
    rng = np.random.default_rng(0)
    colours = np.asarray(image, np.float64).reshape(-1, image.shape[-1])

    def sample(flags: np.ndarray) -> np.ndarray:
        idx = np.flatnonzero(flags.ravel())
        return colours[idx if len(idx) <= _SAMPLE else rng.choice(idx, _SAMPLE, replace=False)]

    inside = sample(hole)
    d_bg, _ = cKDTree(sample(near)).query(inside)
    d_person, _ = cKDTree(sample(around)).query(inside)
    return bool((d_bg < d_person).mean() > share)


def fill_holes(mask: np.ndarray, *, max_hole: float = MAX_HOLE, threshold: float = 0.5,
               image: np.ndarray | None = None) -> tuple[np.ndarray, int, int]:
    """(mask with small enclosed holes set to 1, number of holes filled, number of small holes kept as
    background); ``mask`` (H,W) float in [0,1]. With ``image`` ((H,W,3), the frame), a small hole that
    ``hole_is_background`` is kept."""
    from scipy import ndimage

    fg = mask > threshold
    area = int(fg.sum())
    if area == 0:
        return mask, 0, 0
    holes, n = ndimage.label(~fg)
    if n == 0:
        return mask, 0, 0
    border = np.unique(np.concatenate([holes[0], holes[-1], holes[:, 0], holes[:, -1]]))
    sizes = ndimage.sum_labels(np.ones_like(holes), holes, index=np.arange(1, n + 1))
    fill = [k + 1 for k in range(n) if (k + 1) not in border and sizes[k] <= max_hole * area]
    small = len(fill)
    if image is not None and fill:
        rows = np.flatnonzero(fg.any(1))
        reach = max(BACKGROUND_REACH * (rows[-1] - rows[0] + 1), 4.0)
        fill = [k for k in fill if not hole_is_background(image, fg, holes == k, reach=reach)]
    if not fill:
        return mask, 0, small
    out = mask.copy()
    out[np.isin(holes, fill)] = 1.0
    return out, len(fill), small - len(fill)


def remove_others(mask: np.ndarray, others: np.ndarray | None, own: np.ndarray | None = None) -> np.ndarray:
    """The mask with other people's pixels (``others`` (H,W) bool, not part of ``own``) set to 0."""
    if others is None or not others.any():
        return mask
    drop = others if own is None else (others & ~own)
    out = mask.copy()
    out[drop] = 0.0
    return out
