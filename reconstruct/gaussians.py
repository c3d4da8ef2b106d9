"""The Gaussian set that crosses module boundaries (avatar -> rasterizer -> snapshot)."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class GaussianSet:
    """N 3D Gaussians as torch tensors on one device.

    means (N,3) world positions; scales (N,3) standard deviations along the local axes (linear,
    positive); quats (N,4) rotations as (w, x, y, z), normalised by the consumer;
    opacities (N,) in [0,1]; features (N,C) any per-Gaussian channels (RGB, normals, visibility).
    """

    means: torch.Tensor
    scales: torch.Tensor
    quats: torch.Tensor
    opacities: torch.Tensor
    features: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        shapes = {
            "means": (self.means, (n, 3)),
            "scales": (self.scales, (n, 3)),
            "quats": (self.quats, (n, 4)),
            "opacities": (self.opacities, (n,)),
        }
        for name, (t, shape) in shapes.items():
            if tuple(t.shape) != shape:
                raise ValueError(f"GaussianSet.{name}: expected shape {shape}, found {tuple(t.shape)}")
        if self.features.dim() != 2 or self.features.shape[0] != n:
            raise ValueError(f"GaussianSet.features: expected shape ({n}, C), found {tuple(self.features.shape)}")

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def device(self) -> torch.device:
        return self.means.device

    def to(self, device=None, dtype=None) -> "GaussianSet":
        return GaussianSet(*(t.to(device=device, dtype=dtype) for t in
                             (self.means, self.scales, self.quats, self.opacities, self.features)))

    def with_features(self, features: torch.Tensor) -> "GaussianSet":
        return GaussianSet(self.means, self.scales, self.quats, self.opacities, features)


def quats_aligning_z(normals):
    """(N,4) wxyz quaternions (numpy) rotating the local +Z axis onto each unit normal (N,3): the
    orientation of flat Gaussians lying in a surface."""
    import numpy as np

    normals = np.asarray(normals, np.float64)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normals)
    sin = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(sin, normals @ z)
    axis = axis / np.maximum(sin, 1e-12)[:, None]
    return np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], axis=1)
