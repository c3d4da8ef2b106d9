"""Gaussians that the arms and hands hid in every training frame: their colours are no photo's, so
the unseen side's fill gives them the colours round them.

Why. Where a photo's hand rests on a skirt, or her arms are folded over her coat, what lies behind
the fitted arm (the garment layer, the torso) is reached by the training rays only through the
arm's soft edges and the gaps between its discs. Those Gaussians count as seen (their blend weight
passes ``Stage1Config.seen_min_weight``) or as the fill's ring (a training ray reached them), and
keep the colours training gave them: whatever mixed with the arm in front made the photo's pixels,
skin, white and saturated compensation colours. In the photo's own pose the arm covers them; once
it moves (a walk, another motion) they are a hand-shaped imprint on the cloth, or a band of specks
across the chest where the arms were folded. ``layer_behind_limbs`` catches the layer's that took
the arm's colour; these took any.

Which. Each training frame (up to ``max_frames``) is rendered twice with the colours as a leaf,
once as it is and once with the arms' and hands' Gaussians transparent; the gradient of the summed
image is each Gaussian's blend weight (pixels' worth). A frame shows a Gaussian when the rays reach
it there without the arms (``min_weight`` pixels) and it keeps at least ``share`` of that weight
with them. One that some frame reaches and none shows was hidden by the arms. In a video the arms
swing: a Gaussian behind a hanging arm in most frames and shown in one was seen there. The arms'
own Gaussians are never flagged (one behind the other is the same limb's business).

Use. Stage I's finish (``train/plan.py``, ``Stage1Config.layer_hidden_by_limbs`` for the garment
layer's, ``body_hidden_by_limbs`` for the body's): they are unseen and not in the fill's ring, so
the fill paints them like what surrounds them; the layer's take their colours from the cloth round
the gap (``appearance/gap_fill.py``) and their row's opacity.
"""

from __future__ import annotations

import dataclasses

import torch

from ..avatar.garment_layer import spread_frames
from ..avatar.layer_through import arm_mask
from ..avatar.state import AvatarState
from .data import TrainingData
from .render import render_avatar


def blend_weights(posed, camera, background: torch.Tensor) -> torch.Tensor:
    """(N,) float64: each Gaussian's blend weight (transmittance times alpha) summed over the
    image's pixels, read as the gradient of the rendered image with the colours as a leaf."""
    probe = torch.zeros_like(posed.colors).requires_grad_(True)
    r = render_avatar(dataclasses.replace(posed, colors=probe), camera, background, normals=False)
    r.rgb[..., 0].sum().backward()
    return probe.grad[:, 0].detach().cpu().double()


def arm_gaussians(model) -> torch.Tensor:
    """(N+M,) bool: the body's arm and hand Gaussians (``layer_through.arm_mask``)."""
    arms = arm_mask(model.parts())
    arms[model.num_body:] = False
    return torch.as_tensor(arms)


def hidden_by_limbs(state: AvatarState, data: TrainingData, *, share: float = 0.25, min_weight: float = 0.25,
                    max_frames: int = 8) -> torch.Tensor | None:
    """(N+M,) bool: the Gaussians other than the arms' that the arms and hands hid in every
    training frame that reaches them (up to ``max_frames`` spread over the frames): in some frame
    the rays reach them for at least ``min_weight`` pixels' worth of blend weight with the arms
    transparent, and in none do they keep ``share`` of that with the arms as they are. None
    without training frames."""
    if not 0 < share <= 1:
        raise ValueError(f"hidden_by_limbs: share must be in (0, 1], found {share}")
    if min_weight <= 0:
        raise ValueError(f"hidden_by_limbs: min_weight must be > 0 pixels, found {min_weight}")
    if not len(data.frames):
        return None
    arms = arm_gaussians(state.model)
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
    return reached & ~shown & ~arms
