"""The data a motion file is read into: a source skeleton and its motion (typed, numpy)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np


class MotionFileError(ValueError):
    """A motion file that cannot be read: the message names the file (and the line, for text files)."""


def read_motion_bytes(path: Path) -> bytes:
    """The bytes of a motion file; ``MotionFileError`` naming it when it cannot be read."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise MotionFileError(f"{path}: cannot be read: {exc}") from None


@dataclass(frozen=True)
class SourceSkeleton:
    """The skeleton of a motion file at rest.

    names (J): joint names as in the file. parents (J,): parent index, -1 for the root; parents come
    before their children. offsets (J,3): rest position of each joint relative to its parent (the
    root's: its rest position), in the file's units and axes; all rest rotations are the identity.
    end_sites: joint index -> (3,) offset of the joint's End Site (BVH leaf tips). naming: which
    column of the role table names these joints ("bvh" or "smpl").
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)
    naming: str = "bvh"

    def __post_init__(self) -> None:
        object.__setattr__(self, "parents", np.asarray(self.parents, np.int64))
        object.__setattr__(self, "offsets", np.asarray(self.offsets, np.float64))
        J = len(self.names)
        if self.parents.shape != (J,) or self.offsets.shape != (J, 3):
            raise ValueError(f"SourceSkeleton: {J} names, parents {self.parents.shape}, offsets {self.offsets.shape}")
        if J == 0 or self.parents[0] != -1 or np.any(self.parents[1:] >= np.arange(1, J)) or np.any(self.parents[1:] < 0):
            raise ValueError("SourceSkeleton: parents must form a tree with each parent before its children")

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def rest_positions(self) -> np.ndarray:
        """(J,3) joint positions at rest (file units and axes)."""
        pos = np.zeros((self.num_joints, 3))
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] + (pos[p] if p >= 0 else 0.0)
        return pos

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.nonzero(self.parents == j)[0]]


@dataclass(frozen=True)
class MotionClip:
    """A motion read from a file.

    local_rotations (T,J,3,3): each joint's rotation relative to its parent, the rest pose being the
    identity (file axes). root_positions (T,3): the root joint's position (file units and axes).
    rest_to_body (3,3) turns the rest skeleton's axes into the body's (Z up, facing -Y);
    world_to_body (3,3) turns the file's world axes into the body's (they differ for SMPL sequences,
    whose rest skeleton is SMPL's Y-up T-pose while the world is often Z-up). metres_per_unit: the
    unit guess (informative; retargeting scales by leg length).
    """

    skeleton: SourceSkeleton
    local_rotations: np.ndarray
    root_positions: np.ndarray
    fps: float
    rest_to_body: np.ndarray
    world_to_body: np.ndarray
    metres_per_unit: float
    source: str
    format: str
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        rot = np.asarray(self.local_rotations, np.float64)
        pos = np.asarray(self.root_positions, np.float64)
        object.__setattr__(self, "local_rotations", rot)
        object.__setattr__(self, "root_positions", pos)
        J = self.skeleton.num_joints
        if rot.ndim != 4 or rot.shape[1:] != (J, 3, 3) or pos.shape != (rot.shape[0], 3):
            raise ValueError(f"MotionClip: rotations {rot.shape} and root positions {pos.shape} do not fit {J} joints")
        if rot.shape[0] == 0:
            raise ValueError(f"MotionClip {self.source}: no frames")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"MotionClip {self.source}: frame rate must be positive, found {self.fps}")

    @property
    def num_frames(self) -> int:
        return int(self.local_rotations.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return (self.num_frames - 1) / self.fps

    def with_(self, **changes) -> MotionClip:
        return replace(self, **changes)

    def with_rest_offsets(self, offsets: np.ndarray) -> MotionClip:
        """The same motion on a skeleton with other rest offsets (e.g. an SMPL sequence on the SMPL
        body's own rest joints); the root keeps its motion relative to its rest position."""
        offsets = np.asarray(offsets, np.float64)
        sk = self.skeleton
        skeleton = SourceSkeleton(sk.names, sk.parents, offsets, sk.end_sites, sk.naming)
        return replace(self, skeleton=skeleton, root_positions=self.root_positions + (offsets[0] - sk.offsets[0]))

    def world(self, local_rotations: np.ndarray | None = None, root_positions: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics in the file's world: (T,J,3,3) rotations of each joint relative to the
        rest pose, and (T,J,3) joint positions."""
        L = self.local_rotations if local_rotations is None else local_rotations
        root = self.root_positions if root_positions is None else root_positions
        sk = self.skeleton
        T, J = L.shape[:2]
        Q = np.empty_like(L)
        P = np.empty((T, J, 3))
        for j, p in enumerate(sk.parents):
            if p < 0:
                Q[:, j] = L[:, j]
                P[:, j] = root if j == 0 else sk.offsets[j]
            else:
                Q[:, j] = Q[:, p] @ L[:, j]
                P[:, j] = P[:, p] + Q[:, p] @ sk.offsets[j]
        return Q, P
