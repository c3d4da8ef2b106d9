"""Stage I's seen flags recounted on the person at the end of the stage, before the unseen fill.

Paper Eq. 7 marks a Gaussian seen when it is the first hit of a training ray. During training the
flags accumulate over every step, and a first hit counts wherever the avatar has coverage, also
on pixels the frame's mask calls background: Gaussians that stick out past the silhouette (most
at the sides of the head, seen only at grazing incidence) are marked seen although no pixel of the
person ever showed them. Their colour is not the person's: with a fixed black background they
learn black (the dark rims), with a random one its mean grey. As seen Gaussians they are colour
sources of the unseen fill, and the back of the head took their grey (seed 2 of the garment
benchmark, 10-minute budget: 1,931 such Gaussians, 1,373 on the head; the face-region
front_leak 0.196).

So at the end of Stage I the final avatar is rendered from every training frame once, and a seen
Gaussian stays seen only if it is the first hit (facing the camera, as in ``mark_seen``) of at
least one pixel the mask gives to the person (mask > ``PERSON``). The others become unseen and are
repainted by the fill like the rest of the unseen side. Training itself never reads the flags, so
Stage I's steps are unchanged; painted visibility (edits) still overrides the result.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..avatar.state import facing_hits
from .render import render_avatar

if TYPE_CHECKING:
    from ..avatar.state import AvatarState
    from .data import TrainingData

PERSON = 0.5  # a pixel belongs to the person where its mask exceeds this


@torch.no_grad()
def person_first_hits(state: AvatarState, data: TrainingData, *, hit_threshold: float = 0.5) -> torch.Tensor:
    """(N,) how many pixels of the person, over the training frames, each Gaussian is the first hit
    of while facing the camera (the avatar as it is now, pose corrections included)."""
    n = state.num_gaussians
    counts = torch.zeros(n, dtype=torch.long)
    for i in data.frames:
        tgt = data.targets[i]
        posed = state.posed(i)
        r = render_avatar(posed, tgt.camera, data.background, normals=False, first_hit=True,
                          hit_threshold=hit_threshold)
        hits = facing_hits(r.first_hit[(tgt.mask > PERSON) & (r.first_hit >= 0)], posed, tgt.camera)
        counts += torch.bincount(hits.cpu(), minlength=n)
    return counts


def keep_seen_on_person(state: AvatarState, data: TrainingData, *, hit_threshold: float = 0.5) -> int:
    """Unmark the seen Gaussians that are the first hit of no person pixel in any training frame;
    returns how many were unmarked."""
    on_person = person_first_hits(state, data, hit_threshold=hit_threshold) > 0
    drop = state.seen & ~on_person
    state.seen &= on_person
    return int(drop.sum())
