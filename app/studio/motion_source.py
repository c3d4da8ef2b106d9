"""A motion file as a pose source of the studio's live view (the Pose panel): read and retargeted
onto the avatar's body in a background thread (``BackgroundJob``), then handed to the trainer
thread as a named pose sequence (``TrainerThread.add_pose_sequence``) that is scrubbed and played
like the built-in novel sequences. ``docs/motion.md`` describes the retargeting."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from .jobs import BackgroundJob

MOTION_KEY_PREFIX = "motion:"


@dataclass(frozen=True)
class LoadedMotion:
    """A motion file retargeted onto the avatar: ``poses`` (BodyPose, the scene's world) at ``fps``.
    ``key``: the name of the pose sequence the trainer thread publishes it under."""

    key: str
    path: str
    poses: tuple
    fps: float
    source_frames: int
    source_fps: float
    notes: tuple[str, ...]
    dropped: tuple[str, ...]
    seconds: float  # read + retarget time

    @property
    def name(self) -> str:
        return Path(self.path).name

    def __len__(self) -> int:
        return len(self.poses)


@dataclass
class MotionPanelState:
    """The Pose panel's motion file: the path typed, the loop option, the load in flight, the
    motion loaded last (kept when a later load fails) and the last error."""

    path: str = ""
    loop: bool = False
    job: BackgroundJob | None = None
    loaded: LoadedMotion | None = None
    message: str | None = None
    loads: int = 0  # loads started (makes each sequence key new)

    @property
    def loading(self) -> bool:
        return self.job is not None and not self.job.done


def load_motion_sequence(path, body, scene, *, key: str, loop: bool = False,
                         fps: float | None = None) -> LoadedMotion:
    """Read ``path`` (.bvh / .fbx / .glb / .gltf / SMPL-family .npz) and retarget it onto ``body``, placed on ``scene``'s
    first frame with the floor of its poses, at ``fps`` (default the scene's). Raises
    ``MotionFileError`` / ``ValueError`` naming the file."""
    from app.export import read_motion, retarget_motion

    t0 = time.perf_counter()
    path = str(path).strip()
    if not path:
        raise ValueError("no motion file given: type the path of a .bvh, .fbx, .glb, .gltf or .npz file")
    clip = read_motion(Path(path).expanduser())
    m = retarget_motion(clip, body, scene, fps=fps, loop=loop)
    return LoadedMotion(key, str(m.path), tuple(m.poses), m.fps, m.source_frames, m.source_fps, m.notes, m.dropped,
                        time.perf_counter() - t0)


def start_motion_load(state: MotionPanelState, body, scene, fps: float | None = None) -> BackgroundJob:
    """Start reading ``state.path`` in the background; the caller polls ``state.job``."""
    state.loads += 1
    key = f"{MOTION_KEY_PREFIX}{state.loads}"
    path, loop = state.path, state.loop
    state.message = None
    state.job = BackgroundJob(lambda: load_motion_sequence(path, body, scene, key=key, loop=loop, fps=fps),
                              name="motion-load")
    return state.job
