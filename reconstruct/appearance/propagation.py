"""Appearance propagated from the seen Gaussians to the unseen ones over the body surface: the
built-in prior's pseudo-appearance (DESIGN.md). No learned weights are involved.

The caller decides which Gaussians count as seen (Stage II: the Stage I flags shrunk by ``erode``).
A garment layer's Gaussians are one more part (no twin) and diffuse over the layer's own grid
(``AvatarModel.neighbours``: the layer and the body are not neighbours).

1. Front/back correspondence by body part: an unseen Gaussian takes the colour of the nearest
   seen Gaussian of the same body part to its mirror image through the part's coronal plane
   (the canonical body faces -Y, so the mirror flips y about the part's mean y). A part with no
   seen Gaussian borrows from its left/right twin, then from the whole body.
2. Diffusion over the UV atlas: a screened harmonic fill over the texel grid's 4-neighbourhood
   with the seen Gaussians held fixed, so colours seen at the visibility boundary (the sides the
   turning body showed) spread inwards, weakly pulled towards the mirrored colours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from ..body.parts import MIRROR, PART_INDEX, PART_NAMES


@dataclass(frozen=True)
class PropagationConfig:
    screening: float = 1e-3  # ε: pull of the mirrored colours against diffusion from the seen boundary
    max_mirror_distance: float = 0.15  # metres: farther matches fall back to the diffusion alone


def mirror_colors(positions: np.ndarray, parts: np.ndarray, seen: np.ndarray, colors: np.ndarray,
                  config: PropagationConfig = PropagationConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Colours for every Gaussian (seen ones unchanged) and a mask of the unseen ones that found a
    seen partner within ``max_mirror_distance``."""
    out = colors.copy()
    matched = np.zeros(len(positions), bool)
    all_seen = np.flatnonzero(seen)
    if len(all_seen) == 0:
        return out, matched
    for p in np.unique(parts):
        members = np.flatnonzero(parts == p)
        todo = members[~seen[members]]
        if len(todo) == 0:
            continue
        pool = members[seen[members]]
        if len(pool) == 0:
            twin = PART_INDEX.get(MIRROR.get(PART_NAMES[p], ""), -1) if p < len(PART_NAMES) else -1
            pool = np.flatnonzero((parts == twin) & seen) if twin >= 0 else pool
        if len(pool) == 0:
            pool = all_seen
        query = positions[todo].copy()
        query[:, 1] = 2 * positions[members, 1].mean() - query[:, 1]
        dist, idx = cKDTree(positions[pool]).query(query)
        ok = dist <= config.max_mirror_distance
        out[todo[ok]] = colors[pool[idx[ok]]]
        matched[todo[ok]] = True
    return out, matched


def erode(seen: np.ndarray, neighbours: np.ndarray, iters: int) -> np.ndarray:
    """Seen flags shrunk by ``iters`` texels on the UV grid: the visibility boundary (grazing views)
    and isolated seen specks inside unseen regions are not trusted as colour sources. Measured on
    the default synthetic scene: unseen-view PSNR of the propagated colours 24.37 dB without erosion,
    25.17 dB with 2 iterations, 25.16 dB with 3."""
    seen = seen.copy()
    for _ in range(iters):
        count = np.where(neighbours >= 0, seen[np.maximum(neighbours, 0)], True).sum(1)
        seen &= count >= neighbours.shape[1]
    return seen


# share of a limb's seen Gaussians that ``erode_by_part`` keeps at the least
ERODE_MIN_KEPT = 0.25
# parts seen as narrow strips in a photo (a forearm a few pixels wide): the arms, hands, legs, feet
LIMB_PARTS: tuple[int, ...] = tuple(i for i, n in enumerate(PART_NAMES)
                                    if n.split(".")[0] in ("upperarm", "lowerarm", "hand", "thigh", "shin", "foot"))


def erode_by_part(seen: np.ndarray, neighbours: np.ndarray, parts: np.ndarray, iters: int,
                  min_kept: float = ERODE_MIN_KEPT, limbs: tuple[int, ...] = LIMB_PARTS) -> np.ndarray:
    """``erode`` by ``iters`` texels; each part of ``limbs`` only as far as it keeps at least
    ``min_kept`` of its seen Gaussians (the most eroded of 1..``iters`` texels that does, else 1).

    Erosion trims the ring at a seen region's edge. A limb in a photo is seen as a strip a few
    texels wide, and erosion takes most of it: the few Gaussians left where the strip happened to
    be widest coloured the whole part (the long-skirt photo's left forearm: 8 of 79 left, at the
    wrist, and its sleeve's back came out skin). The torso, head, neck and a garment layer erode
    in full: where erosion takes most of them in a photo, their first hits are speckle between
    another's (the coat photo's layer between the body's Gaussians, 790 -> 60, or the neck under
    the collar and hair, 153 -> 5), and kept, the scarf between the coat's flaps was carried round
    its back. A limb's outermost ring is never trusted: it is its silhouette, blended with what
    lies behind (the grey-skirt photo's upper arm, 25 seen Gaussians against the wall, none after
    1 texel, kept its beige-grey; with none, the limb borrows its twin's colours). On the synthetic
    videos every limb keeps at least a third at 2 texels (a coat's thighs, seen between its flaps:
    0.33-0.38), so they erode as before. ``parts``: (N,) part index of each Gaussian."""
    seen = np.asarray(seen, bool)
    parts = np.asarray(parts)
    levels = [seen]
    for _ in range(iters):
        levels.append(erode(levels[-1], neighbours, 1))
    out = levels[-1].copy()
    for p in np.intersect1d(np.unique(parts[seen]), np.asarray(limbs, parts.dtype)):
        member = parts == p
        need = min_kept * np.count_nonzero(seen & member)
        level = next((lv for lv in levels[:0:-1] if np.count_nonzero(lv & member) >= need), levels[min(1, iters)])
        out[member] = level[member]
    return out


def propagate_colors(positions, parts, seen, colors, neighbours: np.ndarray,
                     config: PropagationConfig = PropagationConfig()) -> torch.Tensor:
    """(N,3) float32: the seen Gaussians' colours kept, the unseen ones solved over the UV atlas as
    the minimiser of  sum_edges |c_i - c_j|^2 + ε sum_unseen |c_i - m_i|^2  with the seen colours
    fixed (a screened harmonic fill: diffusion from the visibility boundary, pulled weakly towards
    the mirrored colours m so islands without a seen boundary still get a colour). ``neighbours``:
    ``texel_neighbours`` of the Gaussians' texels."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    pos = np.asarray(torch.as_tensor(positions).double().cpu())
    col = np.asarray(torch.as_tensor(colors).double().cpu())
    nb = neighbours
    seen_np = np.asarray(torch.as_tensor(seen).bool().cpu())
    mirrored, _ = mirror_colors(pos, np.asarray(parts), seen_np, col, config)
    free = np.flatnonzero(~seen_np)
    if len(free) == 0:
        return torch.as_tensor(col, dtype=torch.float32)
    i_idx = np.repeat(np.arange(len(pos)), 4)
    j_idx = nb.reshape(-1)
    ok = j_idx >= 0
    i_idx, j_idx = i_idx[ok], j_idx[ok]
    N = len(pos)
    A = sp.coo_matrix((np.ones(len(i_idx)), (i_idx, j_idx)), shape=(N, N)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)  # symmetric adjacency
    deg = np.asarray(A.sum(1)).ravel()
    L = sp.diags(deg) - A
    eps = config.screening
    L_ff = L[free][:, free] + sp.identity(len(free)) * eps
    seen_idx = np.flatnonzero(seen_np)
    rhs = eps * mirrored[free] - L[free][:, seen_idx] @ col[seen_idx]
    out = col.copy()
    out[free] = np.asarray(spsolve(L_ff.tocsc(), rhs)).reshape(len(free), 3)
    return torch.as_tensor(np.clip(out, 0.0, 1.0), dtype=torch.float32)
