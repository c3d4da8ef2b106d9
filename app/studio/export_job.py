"""Exports from the studio window without stopping training or the GUI.

Three threads take part:

* the trainer thread hands over a frozen copy of the avatar between two steps
  (``TrainerThread.call_between_steps(Trainer.frozen)``), so the export shows one state of the
  avatar while training goes on;
* a worker thread builds the export plan from that copy, poses the avatar for each frame (torch),
  passes (snapshot, camera) to the GL thread and writes the images it gets back (imageio, into a
  temporary file renamed over the target at the end: ``atomic_output``);
* the GL thread (the window's context: a second EGL context in a process that has a GLX window
  is what DESIGN.md warns against) renders at most ``frames_per_pump`` queued frames per GUI
  frame into an offscreen framebuffer with its own ``SplatRenderer`` and reads them back.

``.ply`` exports (the current frame, the canonical space, or the Pose panel's sequence as a folder
of frames) need no rendering: the worker thread writes them from the frozen copy
(``app.export.write_ply_plan``: atomically, a sequence all or nothing; cancelling leaves nothing).

``ExportSettings.validate`` checks the destination before anything starts: an unwritable path is
refused at once with a message, and nothing in the run folder is touched.
"""

from __future__ import annotations

import queue
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

VIDEO_KINDS = ("orbit", "poses", "walk", "arms_up", "motion")
PLY_KINDS = ("ply_frame", "ply_canonical", "ply_sequence")
KINDS = VIDEO_KINDS + PLY_KINDS
KIND_LABELS = {"orbit": "360° orbit", "poses": "video poses", "walk": "novel: walk cycle", "arms_up": "novel: arms up",
               "motion": "motion file (Pose panel)", "ply_frame": ".ply: current frame",
               "ply_canonical": ".ply: canonical space", "ply_sequence": ".ply: pose sequence (folder)"}
FORMATS = (".mp4", ".gif")


@dataclass
class ExportSettings:
    kind: str = "orbit"
    frames: int = 60  # orbit and novel sequences
    size: int = 512  # pixels (longer side)
    fps: float = 30.0
    out: str = "exports/avatar.mp4"
    mode: str = "rgb"
    frame_index: int = 0  # the pose the orbit and the single .ply show
    # the Pose panel's sequence (a .ply sequence holds it; "motion" videos play the loaded file)
    sequence: str = "video"  # video, walk, arms_up or motion
    motion_poses: tuple | None = None  # the loaded motion file's poses (BodyPose), if any
    motion_name: str | None = None
    motion_fps: float | None = None
    up: str = "y_down"  # .ply frame (docs/ply.md)
    overwrite: bool = False  # replace an existing .ply sequence folder
    splat_format: str = "ply"  # a sequence's files: ply, compressed.ply, splat, spz or sog (one file: its name's)

    @property
    def is_ply(self) -> bool:
        return self.kind in PLY_KINDS

    def validate(self) -> Path:
        from app.export import VIDEO_SUFFIXES, check_destination, check_ply_destination

        if self.kind not in KINDS:
            raise ValueError(f"unknown export kind {self.kind!r}; choose one of {', '.join(KINDS)}")
        needs_motion = self.kind == "motion" or (self.kind == "ply_sequence" and self.sequence == "motion")
        if needs_motion and not self.motion_poses:
            raise ValueError("no motion file is open: open one in the Pose panel first")
        if self.is_ply:
            if self.up not in ("y_down", "z_up"):
                raise ValueError(f"up must be y_down or z_up, found {self.up!r}")
            return check_ply_destination(self.out, sequence=self.kind == "ply_sequence", overwrite=self.overwrite)
        if self.frames < (1 if self.kind == "orbit" else 2) and self.kind in ("orbit", "walk", "arms_up"):
            raise ValueError(f"{KIND_LABELS[self.kind]} needs more frames, found {self.frames}")
        if self.size < 2:
            raise ValueError(f"size must be at least 2 pixels, found {self.size}")
        if not self.fps or self.fps <= 0:
            raise ValueError(f"fps must be positive, found {self.fps}")
        size = (self.size, self.size) if self.kind == "orbit" else None
        return check_destination(self.out, suffixes=VIDEO_SUFFIXES, size=size)

    def plan(self, avatar):
        """The export plan for a ``TrainedAvatar`` (an ``ExportPlan``, or a ``PlyPlan`` for .ply)."""
        from app.export import plan_novel, plan_orbit, plan_poses, plan_sequence

        if self.is_ply:
            return self.ply_plan(avatar)
        if self.kind == "motion":
            # the poses were resampled to the scene's frame rate when the file was opened
            return plan_sequence(avatar, self.out, list(self.motion_poses), fps=self.motion_fps or self.fps,
                                 desc=self.motion_name or "motion", size=self.size)
        if self.kind == "orbit":
            return plan_orbit(avatar, self.out, frames=self.frames, size=self.size, fps=self.fps,
                              frame_index=self.frame_index)
        if self.kind == "poses":
            return plan_poses(avatar, self.out, size=self.size, fps=self.fps)
        return plan_novel(avatar, self.out, self.kind, frames=self.frames, size=self.size, fps=self.fps)

    def ply_plan(self, avatar):
        from app.export import MotionPoses, plan_ply

        if self.kind == "ply_frame":
            return plan_ply(avatar, self.out, frame=self.frame_index)
        if self.kind == "ply_canonical":
            return plan_ply(avatar, self.out, canonical=True)
        if self.sequence == "motion":
            motion = MotionPoses(Path(self.motion_name or "motion"), list(self.motion_poses), self.motion_fps or self.fps)
            return plan_ply(avatar, self.out, motion=motion, overwrite=self.overwrite)
        if self.sequence in ("walk", "arms_up"):
            return plan_ply(avatar, self.out, novel=self.sequence, frames=self.frames, overwrite=self.overwrite)
        return plan_ply(avatar, self.out, scene=avatar.scene, overwrite=self.overwrite)


@dataclass
class ExportPanelState:
    """The export panel's settings, the job in flight and what it last said."""

    settings: ExportSettings = field(default_factory=ExportSettings)
    job: ExportJob | None = None
    message: str | None = None
    saved_screenshots: list[str] = field(default_factory=list)


class ExportJob:
    """One export in flight. GL thread: ``pump(ctx)`` each frame; any thread: ``progress``,
    ``done``, ``error``, ``cancel()``."""

    def __init__(self, settings: ExportSettings, frozen_future, *, background=(0.0, 0.0, 0.0),
                 frames_per_pump: int = 1, pump_budget_s: float = 0.05) -> None:
        self.settings = settings
        self.out = settings.validate()  # raises at once for a bad destination
        self.background = tuple(background)
        self.frames_per_pump = max(1, int(frames_per_pump))
        self.pump_budget_s = pump_budget_s
        self.total = 0
        self.written = 0
        self.error: str | None = None
        self.result: Path | None = None
        self.started = time.perf_counter()
        self.finished_at: float | None = None
        self._future = frozen_future
        self._requests: queue.Queue = queue.Queue(maxsize=2)
        self._images: queue.Queue = queue.Queue(maxsize=2)
        self._cancel = threading.Event()
        self._renderer = None
        self._thread = threading.Thread(target=self._work, name="export", daemon=True)
        self._thread.start()

    # ----- status ----------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    @property
    def progress(self) -> float:
        if self.result is not None:
            return 1.0
        return self.written / self.total if self.total else 0.0

    def cancel(self) -> None:
        self._cancel.set()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    # ----- worker thread ---------------------------------------------------------------------
    def _work(self) -> None:
        from app.export import write_frames
        from reconstruct.atomic import atomic_output

        try:
            frozen = self._future.result(timeout=300)
            plan = self.settings.plan(frozen)
            self.total = len(plan)
            if self.settings.is_ply:
                self._write_ply(plan)
                return

            def images():
                for i, cam in enumerate(plan.cameras):
                    snap = plan.snapshot(i)
                    self._put(self._requests, (snap, cam))
                    image = self._get(self._images)
                    if isinstance(image, BaseException):
                        raise image
                    self.written = i + 1
                    yield image

            with atomic_output(plan.out) as tmp:
                write_frames(images(), tmp, plan.fps)
            self.result = plan.out
        except _Cancelled:
            self.error = "export cancelled (nothing written)"
        except Exception as exc:  # noqa: BLE001 -- shown in the panel; training goes on
            self.error = f"{type(exc).__name__}: {exc}"
            traceback.print_exc()
        finally:
            self.finished_at = time.perf_counter()

    def _write_ply(self, plan) -> None:
        """A .ply plan: written here (no rendering), the progress after each frame; a cancel stops
        it before the next frame and nothing is left behind."""
        from app.export import write_ply_plan

        def progress(done, total):
            self.written = done
            if self._cancel.is_set() and done < len(plan):
                raise _Cancelled()

        if self._cancel.is_set():
            raise _Cancelled()
        write_ply_plan(plan, up=self.settings.up, progress=progress, overwrite=self.settings.overwrite,
                       fmt=self.settings.splat_format if plan.sequence else None)
        self.result = plan.out

    def _put(self, q: queue.Queue, item) -> None:
        while True:
            if self._cancel.is_set():
                raise _Cancelled()
            try:
                q.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def _get(self, q: queue.Queue):
        while True:
            if self._cancel.is_set():
                raise _Cancelled()
            try:
                return q.get(timeout=0.1)
            except queue.Empty:
                continue

    # ----- GL thread -------------------------------------------------------------------------
    def pump(self, ctx) -> int:
        """Render queued frames (at most ``frames_per_pump``, within ``pump_budget_s``) on the
        current GL context. Returns the number rendered. Releases the GL objects when done."""
        from renderer.splat_renderer import SplatRenderer

        if self.done:
            self.release()
            return 0
        count = 0
        t0 = time.perf_counter()
        while count < self.frames_per_pump and time.perf_counter() - t0 < self.pump_budget_s:
            try:
                snap, cam = self._requests.get_nowait()
            except queue.Empty:
                break
            try:
                if self._renderer is None:
                    self._renderer = SplatRenderer(ctx)
                self._renderer.set_snapshot(snap)
                image = self._renderer.render(cam, mode=self.settings.mode, background=self.background,
                                              dtype=np.uint8)[..., :3].copy()
            except Exception as exc:  # noqa: BLE001 -- handed to the worker, which fails the export
                image = exc
            finally:
                ctx.screen.use()
            self._images.put(image)
            count += 1
        return count

    def release(self) -> None:
        if self._renderer is not None:
            self._renderer.release()
            self._renderer = None


class _Cancelled(Exception):
    pass
