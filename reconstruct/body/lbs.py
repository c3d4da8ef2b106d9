"""Linear blend skinning between the canonical pose and any pose, for points and normals.

The canonical pose (limbs apart) is itself a skinned pose of the model's rest mesh, so a canonical
point is mapped back to the rest pose with the inverse of its own blended canonical transform and
then forward with the blended transform of the target pose:

    A_c(x) = sum_j w_j(x) T_j(canonical),   A_p(x) = sum_j w_j(x) T_j(pose),
    x_o = A_p(x) A_c(x)^-1 x_c.

For mesh vertices this reproduces the body model's own posed vertices exactly (x_c = A_c x_rest).
Normals are transformed with the cofactor matrix of the 3x3 part (the inverse transpose up to a
positive factor) and renormalised.
"""

from __future__ import annotations

import torch


def blend(weights: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """Per-point blended 4x4 matrices: weights (N,J) x transforms (...,J,4,4) -> (...,N,4,4)."""
    J = weights.shape[1]
    flat = transforms.reshape(*transforms.shape[:-3], J, 16)
    return (weights @ flat).reshape(*transforms.shape[:-3], weights.shape[0], 4, 4)


def apply_points(M: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    return (M[..., :3, :3] @ points[..., None])[..., 0] + M[..., :3, 3]


def cofactor3(A: torch.Tensor) -> torch.Tensor:
    """Cofactor matrix of (...,3,3): det(A) * A^-T, defined for singular A too."""
    c0 = torch.cross(A[..., 1, :], A[..., 2, :], dim=-1)
    c1 = torch.cross(A[..., 2, :], A[..., 0, :], dim=-1)
    c2 = torch.cross(A[..., 0, :], A[..., 1, :], dim=-1)
    return torch.stack([c0, c1, c2], dim=-2)


def safe_normalize(v: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    return v / torch.sqrt((v * v).sum(-1, keepdim=True) + eps)


def apply_normals(M: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    return safe_normalize((cofactor3(M[..., :3, :3]) @ normals[..., None])[..., 0])


class Skinning:
    """LBS for a fixed set of canonical points (mesh vertices or Gaussian centres).

    weights (N,J) sum to 1 per point; canonical_transforms (J,4,4) map the rest pose to the
    canonical pose. ``to_pose`` takes the pose's transforms (J,4,4) (rest -> pose) and returns the
    per-point matrices mapping canonical to posed space.
    """

    def __init__(self, weights: torch.Tensor, canonical_transforms: torch.Tensor) -> None:
        self.weights = weights
        self.canonical_inverse = torch.linalg.inv(blend(weights, canonical_transforms))

    def to(self, device=None, dtype=None) -> "Skinning":
        out = object.__new__(Skinning)
        out.weights = self.weights.to(device=device, dtype=dtype)
        out.canonical_inverse = self.canonical_inverse.to(device=device, dtype=dtype)
        return out

    def matrices(self, pose_transforms: torch.Tensor) -> torch.Tensor:
        return blend(self.weights, pose_transforms) @ self.canonical_inverse

    def __call__(self, pose_transforms: torch.Tensor, points: torch.Tensor,
                 normals: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        M = self.matrices(pose_transforms)
        return apply_points(M, points), (None if normals is None else apply_normals(M, normals))
