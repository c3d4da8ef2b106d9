"""Person masks worth training on: fill holes a body and its clothes cannot have, remove other people.

A hole is a background region enclosed by the person. Small ones (below ``max_hole`` of the person's
area) are segmenter mistakes and are filled; larger ones are real (a hand on the hip, the gap between
arm and body) and are kept. The GrabCut refinement itself runs with the detector (``grabcut_refine.py``).
"""

from __future__ import annotations

import numpy as np

MAX_HOLE = 0.01  # holes up to 1 % of the person's area are filled


def fill_holes(mask: np.ndarray, *, max_hole: float = MAX_HOLE, threshold: float = 0.5) -> tuple[np.ndarray, int]:
    """(mask with small enclosed holes set to 1, number of holes filled); ``mask`` (H,W) float in [0,1]."""
    from scipy import ndimage

    fg = mask > threshold
    area = int(fg.sum())
    if area == 0:
        return mask, 0
    holes, n = ndimage.label(~fg)
    if n == 0:
        return mask, 0
    border = np.unique(np.concatenate([holes[0], holes[-1], holes[:, 0], holes[:, -1]]))
    sizes = ndimage.sum_labels(np.ones_like(holes), holes, index=np.arange(1, n + 1))
    fill = [k + 1 for k in range(n) if (k + 1) not in border and sizes[k] <= max_hole * area]
    if not fill:
        return mask, 0
    out = mask.copy()
    out[np.isin(holes, fill)] = 1.0
    return out, len(fill)


def remove_others(mask: np.ndarray, others: np.ndarray | None, own: np.ndarray | None = None) -> np.ndarray:
    """The mask with other people's pixels (``others`` (H,W) bool, not part of ``own``) set to 0."""
    if others is None or not others.any():
        return mask
    drop = others if own is None else (others & ~own)
    out = mask.copy()
    out[drop] = 0.0
    return out
