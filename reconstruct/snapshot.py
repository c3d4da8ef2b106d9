"""What training publishes for drawing: plain numpy arrays behind one lock.

The training thread calls ``SnapshotBox.publish`` after a step; the GL thread calls
``SnapshotBox.latest`` each frame. Neither waits on the other beyond the copy of a reference.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Snapshot:
    """Gaussians ready to draw (world space of the chosen ``space``).

    means (N,3) float32; scales (N,3) float32 standard deviations; rotations (N,4) float32
    quaternions (w,x,y,z); colors (N,3) float32 in [0,1]; opacities (N,) float32;
    normals (N,3) float32 unit (observation or canonical, matching ``space``);
    visibility (N,) uint8: 1 where the Gaussian was a first hit on a training ray (paper Eq. 7;
    in Stage II the flags shrunk on the UV grid that view selection used).
    """

    means: np.ndarray
    scales: np.ndarray
    rotations: np.ndarray
    colors: np.ndarray
    opacities: np.ndarray
    normals: np.ndarray
    visibility: np.ndarray
    space: str = "observation"  # "observation" or "canonical"
    frame_index: int = 0
    stage: int = 1
    step: int = 0
    metrics: dict = field(default_factory=dict)
    version: int = 0  # increases whenever the arrays change; renderers re-upload on change
    # optional overlays
    mesh_vertices: np.ndarray | None = None  # (V,3) body mesh in the same space
    mesh_faces: np.ndarray | None = None  # (F,3) int32
    joints: np.ndarray | None = None  # (J,3) joint positions
    joint_parents: np.ndarray | None = None  # (J,) int, -1 for roots
    # edits (reconstruct.edits)
    ids: np.ndarray | None = None  # (N,) int32 Gaussian (texel) index of each row; None: all Gaussians in order
    highlight: np.ndarray | None = None  # (N,) uint8 per row, 1 = selected (EditSession.highlight)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @staticmethod
    def from_gaussians(g, visibility, **meta) -> "Snapshot":
        """From renderable Gaussians (``PosedGaussians``: torch tensors) and per-Gaussian seen flags;
        ``meta`` sets the other fields (space, frame_index, stage, step, metrics)."""
        f32 = lambda t: np.asarray(t.detach().cpu().float())
        return Snapshot(f32(g.means), f32(g.scales), f32(g.quats), f32(g.colors), f32(g.opacities), f32(g.normals),
                        np.asarray(visibility.cpu()).astype(np.uint8), **meta)

    @staticmethod
    def empty() -> "Snapshot":
        z3 = np.zeros((0, 3), np.float32)
        return Snapshot(z3, z3, np.zeros((0, 4), np.float32), z3, np.zeros(0, np.float32), z3, np.zeros(0, np.uint8))


class SnapshotBox:
    """A lock-protected slot holding the latest snapshot."""

    def __init__(self, initial: Snapshot | None = None) -> None:
        self._lock = threading.Lock()
        self._snap = initial if initial is not None else Snapshot.empty()
        self._version = self._snap.version

    def publish(self, snap: Snapshot) -> None:
        with self._lock:
            self._version += 1
            object.__setattr__(snap, "version", self._version)
            self._snap = snap

    def latest(self) -> Snapshot:
        with self._lock:
            return self._snap
