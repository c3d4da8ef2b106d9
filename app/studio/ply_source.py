"""A 3DGS ``.ply`` as something the studio draws: read in a background thread (``BackgroundJob``)
into a ``Snapshot`` with what the file says about itself. Files written by this program record their
frame (``comment wonderhuman up=...``) and come back upright; other programs' files are in the 3DGS
/ COLMAP convention (y down) as a rule, which ``foreign_up`` turns upright (or leaves as stored)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .jobs import BackgroundJob

# how to stand up a file without our comment: (key, label)
FOREIGN_UPS = (("y_down", "y down (3DGS / COLMAP)"), ("z_up", "z up"), ("y_up", "y up"))


@dataclass(frozen=True)
class PlyInfo:
    """A .ply read for viewing: its ``snapshot`` (our frame: Z up) and what the file holds."""

    path: str
    snapshot: object  # reconstruct.snapshot.Snapshot
    num_gaussians: int
    sh_degree: int | None
    recorded_up: str | None  # our writer's comment, or None (a file from elsewhere)
    turned_up: str  # how it was stood up: the recorded frame, or the foreign_up asked for
    has_normals: bool
    file_bytes: int
    seconds: float
    comments: tuple[str, ...]

    @property
    def name(self) -> str:
        return Path(self.path).name

    def summary(self) -> str:
        sh = "?" if self.sh_degree is None else str(self.sh_degree)
        origin = "written by WonderHuman" if self.recorded_up else f"from elsewhere, read as {self.turned_up}"
        return (f"{self.num_gaussians:,} Gaussians, SH degree {sh}, {self.file_bytes / 1e6:.2f} MB, "
                f"{origin}{'' if self.has_normals else ', no normals'}; read in {self.seconds:.2f} s")


def _stand_up(means, normals, rotations, up: str):
    """A foreign file's arrays turned from its frame (``up``) into ours (Z up)."""
    from reconstruct.ply import UP_QUATERNION, UP_ROTATION, quat_multiply

    if up == "z_up":
        return means, normals, rotations
    if up == "y_down":  # ours -> y_down is x' = U x; back: U^T
        R, q = UP_ROTATION.T, UP_QUATERNION * np.array([1.0, -1.0, -1.0, -1.0])
    elif up == "y_up":  # x' = x, y' = z, z' = -y (ours -> y up); back: its transpose
        R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]).T
        q = np.array([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0]) * np.array([1.0, -1.0, -1.0, -1.0])
    else:
        raise ValueError(f"unknown up axis {up!r}; choose one of {[k for k, _ in FOREIGN_UPS]}")
    rot = quat_multiply(q, rotations)
    rot /= np.linalg.norm(rot, axis=1, keepdims=True)
    f32 = lambda a: None if a is None else np.ascontiguousarray(a, np.float32)
    return f32(means @ R.T), f32(None if normals is None else normals @ R.T), f32(rot)


def read_ply_for_view(path, foreign_up: str = "y_down") -> PlyInfo:
    """Read ``path`` (any 3DGS or compressed .ply, .splat, .spz or .sog; ``reconstruct.gaussian_files``)
    for drawing. Raises ``PlyFormatError``
    (a ValueError naming the file, what was expected and found) for a malformed file."""
    import dataclasses

    from reconstruct.gaussian_files import read_gaussians
    from reconstruct.ply import PlyFormatError, ply_to_snapshot

    t0 = time.perf_counter()
    text = str(path).strip()
    if not text:
        raise ValueError("no splat file given: type the path of a 3DGS .ply, .splat, .spz or .sog file")
    path = Path(text).expanduser()
    if path.is_dir():
        raise PlyFormatError(f"{path}: is a folder; open one of its .ply files (e.g. {path / 'frame_0000.ply'})")
    g = read_gaussians(path)
    if len(g) == 0:
        raise PlyFormatError(f"{path}: holds no Gaussians (the vertex element is empty)")
    turned = g.up or foreign_up
    if g.up is None:
        means, normals, rotations = _stand_up(g.means.astype(np.float64), None if g.normals is None
                                              else g.normals.astype(np.float64), g.rotations.astype(np.float64),
                                              foreign_up)
        g = dataclasses.replace(g, means=means, normals=normals, rotations=rotations)
    snap = ply_to_snapshot(g)
    return PlyInfo(str(path), snap, len(g), g.sh_degree, g.up, turned, g.normals is not None, path.stat().st_size,
                   time.perf_counter() - t0, tuple(g.comments))


@dataclass
class PlyFileState:
    """The viewer's file field, the read in flight, the file shown and the last error (a failed
    read keeps the file shown before)."""

    path: str = ""
    foreign_up: str = "y_down"
    job: BackgroundJob | None = None
    loaded: PlyInfo | None = None
    message: str | None = None

    @property
    def loading(self) -> bool:
        return self.job is not None and not self.job.done

    def start(self, path: str | None = None) -> BackgroundJob:
        if path is not None:
            self.path = str(path)
        p, up = self.path, self.foreign_up
        self.message = None
        self.job = BackgroundJob(lambda: read_ply_for_view(p, up), name="ply-read")
        return self.job


def place_beside(live, other, gap: float = 0.25):
    """``live`` (a Snapshot) with ``other``'s Gaussians (a .ply's) added beside it: moved so that
    its bounding box stands on the same floor (lowest Z), centred on the same depth (Y) and
    ``gap`` metres to the live avatar's left (+X: the viewer's right when facing the avatar).
    Keeps ``live``'s version, space and frame; ``other``'s visibility flags are zero."""
    import dataclasses

    if len(other) == 0:
        return live
    if len(live) == 0:
        return other
    lo, hi = live.means.min(0), live.means.max(0)
    olo, ohi = other.means.min(0), other.means.max(0)
    shift = np.array([hi[0] + gap - olo[0], 0.5 * (lo[1] + hi[1]) - 0.5 * (olo[1] + ohi[1]), lo[2] - olo[2]],
                     np.float32)
    cat = lambda a, b: np.concatenate([a, b.astype(a.dtype, copy=False)], 0)
    return dataclasses.replace(
        live, means=cat(live.means, other.means + shift), scales=cat(live.scales, other.scales),
        rotations=cat(live.rotations, other.rotations), colors=cat(live.colors, other.colors),
        opacities=cat(live.opacities, other.opacities), normals=cat(live.normals, other.normals),
        visibility=cat(live.visibility, np.zeros(len(other), live.visibility.dtype)),
        mesh_vertices=None, mesh_faces=None, joints=None, joint_parents=None)
