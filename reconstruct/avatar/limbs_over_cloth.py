"""Arm and hand Gaussians that drew the garment's cloth, not the arm: a fitted hand a little larger
than the photo's, or off it, lies over the garment layer and its Gaussians there took the cloth's
colour.

Why. On the grey-skirt photo the woman's right hand rests on her skirt and her left hand holds its
edge out. The fitted right hand reaches past the photo's hand over the skirt, the fitted left hand
lies below the photo's, by the fabric it holds: about half of both hands' seen Gaussians took the
skirt's grey, and the fill carried the grey round to the palms and the backs of the hands, which
showed grey in a walk and from behind.

Which. In each training frame (up to 8) the seen arm and hand Gaussians and the seen opaque layer
Gaussians are projected; an arm Gaussian with at least ``k_cloth`` of them within ``reach``
(metres in the image plane at its own depth) lies by the cloth, whose colour there is their median.
The limb's own colour is that of the seen Gaussians of the same kind (hands, forearms or upper
arms, both sides together) that lie by no cloth in any of the frames: the photo's hand where it is
not on the skirt (the whole arm's, where fewer than ``k`` of the kind are). An arm Gaussian by the
cloth is flagged when its colour is within ``tolerance`` of the cloth's there and nearer to it
than to the limb's own (colours compared as in ``layer_through.colour_distance``). Nothing is
flagged where the cloth's colour is within ``min_contrast`` of the limb's (a coat's sleeves in
front of the coat: the sleeve is the cloth's colour), and none when more than ``max_share`` of the
seen arm Gaussians would be.

Use. Stage I's finish (``train/plan.py``, ``Stage1Config.limbs_over_cloth``) takes them out of the
colour sources of the unseen side (and of Stage II's propagated appearance): the palms and backs of
the hands take the hand's colours. They keep their own colour, which the photo's own view needs:
unseen and filled like the hand, they drew the hand's colour over the skirt where the fitted hand
sticks out past the photo's (the grey-skirt photo's own view 24.74 -> 23.62 dB inside the mask,
light blotches on the skirt). So the seen face of such a hand keeps the cloth's colour in other
poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body.parts import PART_INDEX
from .layer_through import arm_mask, _split_views, colour_distance, median_colour_within

# the kinds whose own colour is read together, both sides
LIMB_KINDS = (("hand.L", "hand.R"), ("lowerarm.L", "lowerarm.R"), ("upperarm.L", "upperarm.R"))


@dataclass(frozen=True)
class OverClothConfig:
    reach: float = 0.08  # metres in the image plane (at the arm Gaussian's depth) to the layer Gaussians by it
    k_cloth: int = 4  # fewest seen layer Gaussians within reach: the arm Gaussian lies by the cloth
    k: int = 8  # fewest Gaussians for the limb's own colour
    tolerance: float = 0.12  # an arm colour this close to the cloth's there (``colour_distance``) drew it
    min_contrast: float = 0.08  # the cloth's colour this far from the limb's at least, or no telling them apart
    luminance_weight: float = 0.5  # brightness against hue (shading moves brightness)
    min_opacity: float = 0.5  # layer Gaussians less opaque than this are not cloth
    max_share: float = 0.3  # more than this share of the seen arm Gaussians flagged: none is


def limbs_over_cloth(views, body_parts: np.ndarray, body_colors: np.ndarray, body_seen: np.ndarray,
                     layer_colors: np.ndarray, layer_seen: np.ndarray, layer_opacity: np.ndarray | None = None,
                     config: OverClothConfig = OverClothConfig()) -> np.ndarray:
    """(N,) bool over the body's Gaussians: the seen arm and hand Gaussians that lie by the garment
    layer in some training frame and took the cloth's colour (module docstring). ``views``: (camera,
    body_means (N,3), layer_means (M,3)) of the training frames, posed."""
    cfg = config
    parts = np.asarray(body_parts)
    N = len(parts)
    out = np.zeros(N, bool)
    lseen = np.asarray(layer_seen, bool)
    if layer_opacity is not None:
        lseen = lseen & (np.asarray(layer_opacity, np.float64) >= cfg.min_opacity)
    cand = np.flatnonzero(arm_mask(parts) & np.asarray(body_seen, bool))
    cloth = np.flatnonzero(lseen)
    if len(cand) < cfg.k or len(cloth) < cfg.k:
        return out
    w = cfg.luminance_weight
    own = np.asarray(body_colors, np.float64)[cand]
    ccol = np.asarray(layer_colors, np.float64)[cloth]
    # the cloth's colour by each arm Gaussian, in the first frame with some
    under = median_colour_within(views, (2, cloth), ccol, (1, cand), cfg.reach, cfg.k_cloth)
    over = np.isfinite(under[:, 0])
    if not over.any():
        return out
    kind_of = np.full(len(cand), -1)
    for i, names in enumerate(LIMB_KINDS):
        kind_of[np.isin(parts[cand], [PART_INDEX[p] for p in names])] = i
    whole = own[~over]
    for i in range(len(LIMB_KINDS)):
        mine = kind_of == i
        free = own[mine & ~over]
        ref = free if len(free) >= cfg.k else whole
        j = np.flatnonzero(mine & over)
        if len(ref) < cfg.k or not len(j):
            continue
        limb = np.median(ref, axis=0)[None]
        to_cloth = colour_distance(own[j], under[j], w)
        like = ((colour_distance(under[j], limb, w) >= cfg.min_contrast) & (to_cloth <= cfg.tolerance)
                & (to_cloth < colour_distance(own[j], limb, w)))
        out[cand[j[like]]] = True
    if out.sum() > cfg.max_share * len(cand):
        return np.zeros(N, bool)
    return out


def model_limbs_over_cloth(model, seen, colors, views,
                           config: OverClothConfig = OverClothConfig()) -> np.ndarray | None:
    """``limbs_over_cloth`` for an ``AvatarModel``: (N+M,) bool (False on the layer's) from the
    (N+M,) ``seen`` flags and canonical ``colors``; ``views``: (camera, posed means (N+M,3)) of the
    training frames. None without a layer."""
    if model.layer is None or model.num_layer == 0:
        return None
    N, col, seen, split, opacity = _split_views(model, seen, colors, views)
    flags = limbs_over_cloth(split, model.parts()[:N], col[:N], seen[:N], col[N:], seen[N:], opacity, config)
    return np.concatenate([flags, np.zeros(model.num_layer, bool)])
