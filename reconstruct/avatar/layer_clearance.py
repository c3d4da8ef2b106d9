"""A garment layer kept outside the posed body: cloth the legs would poke through is pushed out.

Why. The layer is built outside the canonical body (its rings are the body slices' convex hull plus
a standoff), but it is skinned with weights blended across the legs so that it moves as one piece.
In a pose whose legs turn or spread, a thigh moves with its own bone only, the cloth over it with a
blend: the back of a thigh comes out through the coat's back panel. On a photo of a woman standing
in a long coat, 10.8 % of the layer's Gaussians were inside the posed body, up to 4 cm deep; seen
from behind, a dark strip of trouser ran down the coat from the seat to the hem.

How. The body Gaussians of the parts the layer covers (torso, thighs, shins; the arms may lie on
the cloth and stay out of it) are posed at their surface points with the body's surface normals.
For each layer Gaussian the nearest of those in posed space (a k-d tree, rebuilt for each pose:
the legs' layout changes with the pose, so canonical neighbours are no guide) is its body surface
point. When the Gaussian is less than ``clearance`` in front of that surface along its normal, it
is moved along the normal to ``clearance``. The move is a correction without a gradient (a
collision response): the layer's means keep the gradient they have, the body does not move, and a
Gaussian already clear of the body is untouched (so a canonical-space render and a pose with clear
cloth are exactly what they were).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from scipy.spatial import cKDTree

from ..body.parts import PART_INDEX

# body parts a garment layer covers (the body surface it must stay outside of)
COVERED_PARTS = ("torso", "thigh.L", "thigh.R", "shin.L", "shin.R")


def covered_ids(body_parts: np.ndarray) -> np.ndarray:
    """(U,) int64: the body Gaussians of the parts a garment layer covers."""
    ids = np.flatnonzero(np.isin(np.asarray(body_parts), [PART_INDEX[p] for p in COVERED_PARTS]))
    if len(ids) == 0:
        raise ValueError("garment layer clearance: the body has none of the parts " + ", ".join(COVERED_PARTS))
    return ids.astype(np.int64)


def push_out(layer_means: torch.Tensor, surface_points: torch.Tensor,
             surface_normals: torch.Tensor | Callable[[torch.Tensor], torch.Tensor], clearance: float) -> torch.Tensor:
    """``layer_means`` (L,3) moved to at least ``clearance`` in front of their nearest point of the
    surface ``surface_points`` (U,3, posed) along its unit normal: ``surface_normals`` (U,3), or a
    function giving the normals of the points at the indices it is passed (so that only the
    nearest points' are computed). The move carries no gradient."""
    with torch.no_grad():
        p = layer_means.detach()
        # built for each pose; an unbalanced tree builds in about half the time and queries as fast
        tree = cKDTree(surface_points.detach().cpu().double().numpy(), balanced_tree=False, compact_nodes=False)
        _, j = tree.query(p.cpu().double().numpy())
        j = torch.as_tensor(np.asarray(j), device=surface_points.device)
        n = (surface_normals(j) if callable(surface_normals) else surface_normals[j]).to(p)
        depth = ((p - surface_points[j].to(p)) * n).sum(dim=1)
        move = (clearance - depth).clamp_min(0.0)[:, None] * n
    return layer_means + move
