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
trainer composites behind it.

The ring. A segmenter's mask is rarely exactly where the person ends: its first full pixels may
still hold background. On the grey-skirt photo (dark floor behind the shins, 360 x 512) the full
pixels next to the band were 0.27-0.44 in luminance against 0.6-0.7 on the shin three pixels in,
and filling the band from them carried the dark floor outwards: the avatar drew a dotted dark rim
down each shin, and from the side the shins showed dark streaks. So the colours come from the
full region shrunk by ``RING`` pixels (its core): the ring of full pixels outside the core takes
the nearest core colour too. Where the core is not right behind a pixel -- a part no wider than
twice the ring, a finger or a strap, whose own core is gone -- the nearest core colour would be
another part's, so there the ring keeps its own colours and the band takes the nearest full one,
as without a ring.
"""

from __future__ import annotations

import numpy as np

# mask values from which a pixel counts as fully the person
FULL = 0.98
# px: full pixels this close to the band (or the mask's edge) take the colour of the core behind them
RING = 2


def decontaminate(rgb: np.ndarray, mask: np.ndarray, *, full: float = FULL, ring: int = RING) -> np.ndarray:
    """(H,W,3) ``rgb`` (not premultiplied) with every pixel whose ``mask`` (H,W, in [0,1]) is below
    ``full`` given the colour of the nearest pixel at or above it; with ``ring`` > 0, the colour of
    the nearest pixel of the full region's core (its pixels more than ``ring`` px from any pixel
    that is not full), which the ring of full pixels outside the core takes too, wherever that
    core pixel lies right behind the nearest full one (see the module docstring). Unchanged when
    no pixel is full or every pixel is."""
    from scipy import ndimage

    rgb = np.asarray(rgb)
    mask = np.asarray(mask)
    if rgb.shape[:2] != mask.shape:
        raise ValueError(f"decontaminate: image {rgb.shape[:2]} and mask {mask.shape} differ in size")
    if int(ring) != ring or ring < 0:
        raise ValueError(f"decontaminate: ring must be a whole number of pixels >= 0, found {ring!r}")
    inside = mask >= full
    if not inside.any() or inside.all():
        return rgb.copy()
    d_in, (iy, ix) = ndimage.distance_transform_edt(~inside, return_indices=True)
    out = rgb[iy, ix]
    out[inside] = rgb[inside]
    if ring == 0:
        return out
    depth = ndimage.distance_transform_edt(inside)  # inside: px to the nearest pixel that is not full
    core = depth > ring
    if not core.any():
        return out
    d_core, (cy, cx) = ndimage.distance_transform_edt(~core, return_indices=True)
    # the core lies right behind: no farther than the way in plus the ring, with 1.5 px of slack for
    # the grid's diagonals; for a full pixel of the ring the way in is 0
    behind = ~core & (d_core <= np.where(inside, 0.0, d_in) + ring + 1.5)
    out[behind] = rgb[cy[behind], cx[behind]]
    return out
