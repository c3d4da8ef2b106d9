"""The body-model interface every backend (Anny, SMPL) implements."""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property

import numpy as np
import torch

from .lbs import Skinning, apply_points, blend
from .parts import PART_INDEX, part_of_bone
from .pose import BodyPose


def vertex_normals(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted vertex normals (V,3) of a triangle mesh."""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    fn = torch.cross(v1 - v0, v2 - v0, dim=-1)
    vn = torch.zeros_like(vertices)
    for k in range(3):
        vn.index_add_(0, faces[:, k], fn)
    return vn / vn.norm(dim=-1, keepdim=True).clamp_min(1e-12)


class BodyModel(ABC):
    """A skinned body with a UV layout. All tensors are float64 on the CPU; consumers cast.

    Subclasses set: ``name``, ``bone_labels`` (J), ``bone_parents`` (J,), ``faces`` (F,3) long,
    ``rest_vertices`` (V,3), ``rest_joints`` (J,3) bone heads at rest, ``skin_weights`` (V,J) dense,
    ``uv_coords`` (T,2) in [0,1] with v up, ``face_uv_indices`` (F,3), and implement
    ``rest_to_pose_transforms``.
    """

    name: str
    bone_labels: list[str]
    bone_parents: np.ndarray
    faces: torch.Tensor
    rest_vertices: torch.Tensor
    rest_joints: torch.Tensor
    skin_weights: torch.Tensor
    uv_coords: torch.Tensor
    face_uv_indices: torch.Tensor

    @property
    def num_joints(self) -> int:
        return len(self.bone_labels)

    @abstractmethod
    def rest_to_pose_transforms(self, joint_rotations: torch.Tensor) -> torch.Tensor:
        """(J,4,4) skinning transforms from the rest mesh to the pose given by per-joint
        axis-angle rotations (J,3) in world-aligned axes about each joint, without global motion."""

    @abstractmethod
    def canonical_joint_rotations(self) -> np.ndarray:
        """(J,3) the canonical pose: limbs apart (A-pose, legs slightly spread)."""

    def excluded_uv(self, uv: np.ndarray) -> np.ndarray:
        """Bool mask over UV points (N,2) of inner surfaces to leave out (cavities, eyes, tongue)."""
        return np.zeros(len(uv), bool)

    # ----- poses ----------------------------------------------------------------------------
    def bone_transforms(self, pose: BodyPose) -> torch.Tensor:
        """(J,4,4) transforms from the rest mesh to ``pose`` including its global rotation and
        translation."""
        f64 = dict(dtype=torch.float64)
        return self.bone_transforms_t(torch.as_tensor(pose.joint_rotations, **f64),
                                      torch.as_tensor(pose.global_orient, **f64), torch.as_tensor(pose.transl, **f64))

    def bone_transforms_t(self, joint_rotations: torch.Tensor, global_orient: torch.Tensor,
                          transl: torch.Tensor) -> torch.Tensor:
        """Differentiable ``bone_transforms`` on float64 tensors (used by pose refinement)."""
        from .pose import axis_angle_to_matrix, rigid

        G = rigid(axis_angle_to_matrix(global_orient), transl)
        return G @ self.rest_to_pose_transforms(joint_rotations)

    def canonical_pose(self) -> BodyPose:
        return BodyPose(self.canonical_joint_rotations(), np.zeros(3), np.zeros(3))

    @cached_property
    def canonical_transforms(self) -> torch.Tensor:
        return self.bone_transforms(self.canonical_pose())

    def posed_vertices(self, pose: BodyPose) -> torch.Tensor:
        return apply_points(blend(self.skin_weights, self.bone_transforms(pose)), self.rest_vertices)

    def posed_joints(self, pose: BodyPose) -> torch.Tensor:
        return apply_points(self.bone_transforms(pose), self.rest_joints)

    # ----- canonical space --------------------------------------------------------------------
    @cached_property
    def canonical_vertices(self) -> torch.Tensor:
        return apply_points(blend(self.skin_weights, self.canonical_transforms), self.rest_vertices)

    @cached_property
    def canonical_normals(self) -> torch.Tensor:
        return vertex_normals(self.canonical_vertices, self.faces)

    @cached_property
    def canonical_joints(self) -> torch.Tensor:
        return apply_points(self.canonical_transforms, self.rest_joints)

    def skinning(self, weights: torch.Tensor) -> Skinning:
        """LBS for canonical points carrying ``weights`` (N,J)."""
        return Skinning(weights.to(torch.float64), self.canonical_transforms)

    @cached_property
    def vertex_parts(self) -> np.ndarray:
        """(V,) body-part index of each vertex (by its dominant bone)."""
        bone_part = np.array([PART_INDEX[part_of_bone(b)] for b in self.bone_labels])
        return bone_part[self.skin_weights.argmax(dim=1).numpy()]

    @cached_property
    def height(self) -> float:
        z = self.canonical_vertices[:, 2]
        return float(z.max() - z.min())
