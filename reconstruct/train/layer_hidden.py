"""Garment-layer Gaussians that the arms and hands hid in every training frame: their colours are
no photo's, so the unseen side's fill gives them the cloth's.

Why. Where a photo's hand rests on a skirt, the layer behind the fitted hand is reached by the
training rays only through the hand's soft edges and its gaps between discs. Those Gaussians count
as seen (their blend weight passes ``Stage1Config.seen_min_weight``) or as the fill's ring (a
training ray reached them), and keep the colours training gave them: whatever mixed with the hand
in front made the photo's pixels, skin, white and saturated compensation colours. In the photo's
own pose the hand covers them; once the arm moves (a walk, another motion) they are a hand-shaped
imprint on the cloth. ``layer_behind_limbs`` catches those that took the arm's colour; these took
any.

Which. Each training frame (up to ``max_frames``) is rendered twice with the colours as a leaf,
once as it is and once with the arms' and hands' Gaussians transparent; the gradient of the summed
image is each Gaussian's blend weight (pixels' worth). A frame shows a layer Gaussian when the rays
reach it there without the arms (``min_weight`` pixels) and it keeps at least ``share`` of that
weight with them. One that some frame reaches and none shows was hidden by the arms. (In a video
the arms swing: a Gaussian behind a hanging arm in most frames and shown in one was seen there.) Its colour made little of the photo's pixels, and giving it
the cloth's changes the photo's own view little (tested below the hand's edge).

Use. Stage I's finish (``train/plan.py``, ``Stage1Config.layer_hidden_by_limbs``): they are unseen
and not in the fill's ring, so the fill paints them like the cloth around them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..avatar.garment_layer import spread_frames
from ..avatar.layer_through import ARM_PARTS
from ..avatar.state import AvatarState
from ..body.parts import PART_INDEX
from .data import TrainingData
from .render import render_avatar


def blend_weights(posed, camera, background: torch.Tensor) -> torch.Tensor:
    """(N,) float64: each Gaussian's blend weight (transmittance times alpha) summed over the
    image's pixels, read as the gradient of the rendered image with the colours as a leaf."""
    probe = torch.zeros_like(posed.colors).requires_grad_(True)
    r = render_avatar(dataclasses.replace(posed, colors=probe), camera, background, normals=False)
    r.rgb[..., 0].sum().backward()
    return probe.grad[:, 0].detach().cpu().double()


def layer_hidden_by_limbs(state: AvatarState, data: TrainingData, *, share: float = 0.25, min_weight: float = 0.25,
                          max_frames: int = 8) -> torch.Tensor | None:
    """(N+M,) bool: the garment-layer Gaussians the arms and hands hid in every training frame that
    reaches them (up to ``max_frames`` spread over the frames): in some frame the rays reach them for
    at least ``min_weight`` pixels' worth of blend weight with the arms transparent, and in none do
    they keep ``share`` of that with the arms as they are. None without a layer or frames."""
    if not 0 < share <= 1:
        raise ValueError(f"layer_hidden_by_limbs: share must be in (0, 1], found {share}")
    if min_weight <= 0:
        raise ValueError(f"layer_hidden_by_limbs: min_weight must be > 0 pixels, found {min_weight}")
    model = state.model
    if model.layer is None or model.num_layer == 0 or not len(data.frames):
        return None
    nb = model.num_body
    arms = torch.zeros(state.num_gaussians, dtype=torch.bool)
    arms[:nb] = torch.as_tensor(np.isin(np.asarray(model.parts())[:nb], [PART_INDEX[p] for p in ARM_PARTS]))
    reached = torch.zeros(state.num_gaussians, dtype=torch.bool)
    shown = torch.zeros_like(reached)
    for i in spread_frames(list(data.frames), max_frames):
        cam = data.targets[i].camera
        with torch.no_grad():
            posed = state.posed(i)
        with_arms = blend_weights(posed, cam, data.background)
        opacities = posed.opacities.clone()
        opacities[arms.to(opacities.device)] = 0
        without = blend_weights(dataclasses.replace(posed, opacities=opacities), cam, data.background)
        here = without >= min_weight
        reached |= here
        shown |= here & (with_arms >= share * without)
    hidden = reached & ~shown
    hidden[:nb] = False
    return hidden
