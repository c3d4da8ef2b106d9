"""Edge colours without the background: the person's colours in the soft band of the mask.

Why. A pixel on the person's outline is a blend of the person and the background behind them, and
the soft mask says how much of each. ``prepare`` stored ``image * mask``: the background's share of
the blend stayed in the colour. Against a white studio wall the band round the person was 0.5-0.65
lighter than the person's colour next to it (mean luminance of the un-premultiplied colour minus
that of the nearest pixel inside, green-coat photo); against a dark blue one, 0.12-0.15 darker.
The Gaussians on the silhouette learnt that halo as their colour. From the front it is a thin rim;
from the side, where those Gaussians face the camera, it is white streaks down the coat's sides.

What. In the soft band (mask below ``FULL``) the colour is the person's colour at the nearest pixel
that the mask calls fully the person (a nearest-neighbour fill from inside, the usual colour
decontamination when the background's colour is not modelled); the mask is unchanged, so the
stored ``colour * mask`` blends the person's colour, not the background's, over whatever the
trainer composites behind it. Pixels the mask calls fully the person keep theirs.
"""

from __future__ import annotations

import numpy as np

# mask values from which a pixel counts as fully the person
FULL = 0.98


def decontaminate(rgb: np.ndarray, mask: np.ndarray, *, full: float = FULL) -> np.ndarray:
    """(H,W,3) ``rgb`` (not premultiplied) with every pixel whose ``mask`` (H,W, in [0,1]) is below
    ``full`` given the colour of the nearest pixel at or above it. Unchanged when none is."""
    from scipy import ndimage

    rgb = np.asarray(rgb)
    mask = np.asarray(mask)
    if rgb.shape[:2] != mask.shape:
        raise ValueError(f"decontaminate: image {rgb.shape[:2]} and mask {mask.shape} differ in size")
    inside = mask >= full
    if not inside.any() or inside.all():
        return rgb.copy()
    _, (iy, ix) = ndimage.distance_transform_edt(~inside, return_indices=True)
    out = rgb[iy, ix]
    out[inside] = rgb[inside]
    return out
