"""Skinning weights for loose garments: the body's weights carried onto the cloth and diffused
along it, so that the cloth between the legs blends the two legs' bones and moves as one piece.

1. Transfer. Each garment vertex takes a Gaussian-weighted average of the skinning weights of the
   ``k`` nearest canonical body vertices of the parts the garment covers, the Gaussian measured
   relative to the nearest one (``exp(-(d^2 - d_min^2) / 2 sigma^2)``): in front of a thigh the
   thigh wins, on the centre line between the legs both legs count about equally.
2. Diffusion. The weights are smoothed over the mesh's edges (``iterations`` steps of Laplacian
   averaging with ``rate``), which spreads the left-right blend over the width of the cloth between
   the legs and down from the waist, so no edge is pulled between two unrelated bones (the
   nearest-vertex weights that tear a skirt in two are exactly what this avoids). The lining
   shares its outside's weights (a vertex of the lining gets the weights of the outer vertex at
   the same grid place), so the shell keeps its thickness.

The result is continuous over the mesh: LBS can stretch the cloth but cannot open a gap in it.
``max_edge_stretch`` measures how far it is stretched.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy import sparse
from scipy.spatial import cKDTree

from ...body.base import BodyModel
from ...body.parts import PART_INDEX
from ...body.pose import BodyPose
from .garment_mesh import GarmentMesh

_COVERED = ("torso", "thigh.L", "thigh.R", "shin.L", "shin.R")


def transfer_weights(body: BodyModel, points: np.ndarray, *, k: int = 24, sigma: float = 0.04,
                     parts: tuple[str, ...] = _COVERED) -> np.ndarray:
    """(N,J) skinning weights for canonical ``points``, averaged from the nearest body vertices of
    ``parts`` (Gaussian in distance relative to the nearest, ``sigma`` metres)."""
    verts = body.canonical_vertices.numpy()
    sel = np.isin(body.vertex_parts, [PART_INDEX[p] for p in parts])
    if sel.sum() < k:
        raise ValueError(f"garment skinning: only {int(sel.sum())} body vertices on {parts}")
    W = body.skin_weights.numpy()[sel]
    d, idx = cKDTree(verts[sel]).query(np.asarray(points, float), k=k)
    g = np.exp(-(d ** 2 - d[:, :1] ** 2) / (2 * sigma ** 2))
    g /= g.sum(1, keepdims=True)
    return np.einsum("nk,nkj->nj", g, W[idx])


def diffuse_weights(weights: np.ndarray, edges: np.ndarray, n: int, *, iterations: int = 60,
                    rate: float = 0.5) -> np.ndarray:
    """Laplacian smoothing of per-vertex ``weights`` (n,J) over the graph ``edges`` (E,2)."""
    i, j = edges[:, 0], edges[:, 1]
    A = sparse.coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    deg = np.asarray(A.sum(1)).ravel()
    P = sparse.diags(1.0 / np.maximum(deg, 1)) @ A
    w = weights.copy()
    for _ in range(iterations):
        w = (1 - rate) * w + rate * (P @ w)
    w = np.clip(w, 0.0, None)
    return w / w.sum(1, keepdims=True)


def garment_weights(body: BodyModel, garment: GarmentMesh, *, iterations: int = 300) -> np.ndarray:
    """(V,J) skinning weights of ``garment``'s vertices (see the module docstring)."""
    outer = np.flatnonzero(garment.outer)
    w = transfer_weights(body, garment.vertices)
    # diffuse over the outer surface only (its grid edges), then copy onto the lining
    e = garment.edges
    on = garment.outer[e[:, 0]] & garment.outer[e[:, 1]]
    w = diffuse_weights(w, e[on], len(garment.vertices), iterations=iterations)
    key = lambda m: garment.tube[m] * 10 ** 8 + garment.grid_index[m, 0] * 10 ** 4 + garment.grid_index[m, 1]
    lookup = dict(zip(key(outer).tolist(), outer.tolist()))
    inner = np.flatnonzero(~garment.outer)
    w[inner] = w[[lookup[x] for x in key(inner).tolist()]]
    return w


def pose_garment(body: BodyModel, garment: GarmentMesh, weights: np.ndarray, pose: BodyPose) -> np.ndarray:
    """(V,3) the garment's vertices in ``pose`` (LBS with ``weights`` from the canonical pose)."""
    skin = body.skinning(torch.as_tensor(weights, dtype=torch.float64))
    pts, _ = skin(body.bone_transforms(pose), torch.as_tensor(garment.vertices, dtype=torch.float64))
    return pts.numpy()


def max_edge_stretch(canonical: np.ndarray, posed: np.ndarray, edges: np.ndarray) -> float:
    """The largest ratio posed / canonical length over ``edges`` (1 = no stretch)."""
    l0 = np.linalg.norm(canonical[edges[:, 0]] - canonical[edges[:, 1]], axis=1)
    l1 = np.linalg.norm(posed[edges[:, 0]] - posed[edges[:, 1]], axis=1)
    ok = l0 > 1e-9
    return float((l1[ok] / l0[ok]).max())
