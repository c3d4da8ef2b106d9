"""What crosses the avatar's boundary per Gaussian: the canonical Gaussians the decoder makes, the
posed ones the rasterizer draws, and the quaternions of a disc's tangent frame (shared by the
body's texel Gaussians and a garment layer's)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..body.lbs import safe_normalize


@dataclass
class CanonicalGaussians:
    means: torch.Tensor  # (N,3) x_c
    normals: torch.Tensor  # (N,3) n_c, unit
    colors: torch.Tensor  # (N,3) in [0,1]
    scales: torch.Tensor  # (N,3) standard deviations along the Gaussian's own axes
    offsets_raw: torch.Tensor  # (N,3) Δx in head units (Δx = offset_scale * raw): the regulariser's input
    features: torch.Tensor  # the feature map S that produced them (for its regulariser)
    tangents: torch.Tensor | None = None  # (N,3) unit first axis of a disc (None: sphere, identity rotation)
    index: torch.Tensor | None = None  # which of the model's Gaussians these are (None: all, in order)
    opacities: torch.Tensor | None = None  # (N,) in (0,1]; None: all opaque (a model without a garment layer)


@dataclass
class PosedGaussians:
    means: torch.Tensor
    normals: torch.Tensor
    colors: torch.Tensor
    scales: torch.Tensor
    quats: torch.Tensor
    opacities: torch.Tensor


def frame_quaternions(tangents: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """Unit (w, x, y, z) quaternions of the rotations whose columns are (t, n x t, n) for unit
    normals ``n`` and tangents ``t`` (made perpendicular to ``n`` here).

    For a rotation matrix m, the four vectors (1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01),
    (m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20), (m02 - m20, m01 + m10, 1 - m00 + m11 - m22,
    m12 + m21), (m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22) are 4 q_k q for k = w, x, y, z;
    the one with the largest k-th entry (4 q_k^2 >= 1) is normalised: no square root, no division
    by a small number, smooth within each branch."""
    t = safe_normalize(tangents - (tangents * normals).sum(-1, keepdim=True) * normals)
    b = torch.linalg.cross(normals, t, dim=-1)
    m = torch.stack([t, b, normals], dim=-1)  # columns
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    a = m[..., 2, 1] - m[..., 1, 2]
    c = m[..., 0, 2] - m[..., 2, 0]
    d = m[..., 1, 0] - m[..., 0, 1]
    e = m[..., 0, 1] + m[..., 1, 0]
    f = m[..., 0, 2] + m[..., 2, 0]
    g = m[..., 1, 2] + m[..., 2, 1]
    diag = torch.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    cand = torch.stack([torch.stack([diag[..., 0], a, c, d], -1), torch.stack([a, diag[..., 1], e, f], -1),
                        torch.stack([c, e, diag[..., 2], g], -1), torch.stack([d, f, g, diag[..., 3]], -1)], -2)
    k = diag.detach().argmax(-1)
    q = torch.gather(cand, -2, k[..., None, None].expand(*k.shape, 1, 4))[..., 0, :]
    return q / q.norm(dim=-1, keepdim=True)
