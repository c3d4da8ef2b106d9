"""Body poses and rotation helpers (torch, differentiable, float32 or float64)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class BodyPose:
    """A pose of a skeleton with J bones.

    joint_rotations (J,3): axis-angle rotation of each bone about its head, in world-aligned axes
    (the body model's canonical frame; Anny calls this 'local-ref'). global_orient (3,) axis-angle and
    transl (3,) apply a rigid motion to the whole posed body, about the world origin.
    """

    joint_rotations: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray

    def __post_init__(self) -> None:
        self.joint_rotations = np.asarray(self.joint_rotations, np.float64)
        self.global_orient = np.asarray(self.global_orient, np.float64).reshape(3)
        self.transl = np.asarray(self.transl, np.float64).reshape(3)
        if self.joint_rotations.ndim != 2 or self.joint_rotations.shape[1] != 3:
            raise ValueError(f"BodyPose.joint_rotations: expected shape (J, 3), found {self.joint_rotations.shape}")
        for name in ("joint_rotations", "global_orient", "transl"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"BodyPose.{name} contains non-finite values")

    @classmethod
    def zeros(cls, num_joints: int) -> "BodyPose":
        return cls(np.zeros((num_joints, 3)), np.zeros(3), np.zeros(3))

    def to_vector(self) -> np.ndarray:
        return np.concatenate([self.global_orient, self.transl, self.joint_rotations.reshape(-1)])

    @classmethod
    def from_vector(cls, vec: np.ndarray, num_joints: int) -> "BodyPose":
        vec = np.asarray(vec, np.float64).reshape(-1)
        if vec.shape[0] != 6 + 3 * num_joints:
            raise ValueError(f"pose vector: expected {6 + 3 * num_joints} values for {num_joints} joints, found {vec.shape[0]}")
        return cls(vec[6:].reshape(num_joints, 3), vec[:3], vec[3:6])


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula for (..., 3) axis-angle vectors; smooth at zero (Taylor terms)."""
    theta2 = (aa * aa).sum(-1, keepdim=True)
    small = theta2 < 1e-12
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(theta2_safe)
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2_safe)
    x, y, z = aa.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*aa.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand(K.shape)
    return eye + a[..., None] * K + b[..., None] * (K @ K)


def rigid(rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """(...,3,3) and (...,3) to (...,4,4) homogeneous matrices."""
    top = torch.cat([rotation, translation[..., None]], dim=-1)
    bottom = torch.zeros(*rotation.shape[:-2], 1, 4, dtype=rotation.dtype, device=rotation.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)
