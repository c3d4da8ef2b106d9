"""Headless export of a trained avatar: 360° orbit videos, pose sequences (the video's, a novel
one, or a motion file retargeted onto the avatar), screenshots, and the Gaussians themselves as
3DGS ``.ply`` files (one pose, or one file per frame into a folder; ``reconstruct/ply.py``).

Frames are drawn offscreen with ``SplatRenderer`` (EGL) and written by imageio: ``.mp4``
(ffmpeg through imageio-ffmpeg, libx264, yuv420p: width and height must be even), ``.gif``
(per-frame duration from the fps, loops forever) and ``.png`` (one screenshot). Files are written
atomically: to a hidden temporary file in the destination folder that is renamed over the target
at the end and removed on any error.

Every export takes a ``reconstruct.train.trainer.TrainedAvatar`` (``Trainer.avatar()``, or
``Trainer.frozen()`` while training goes on).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reconstruct.atomic import atomic_output
from reconstruct.gaussian_files import FORMATS as SPLAT_FORMATS
from reconstruct.gaussian_files import GAUSSIAN_SUFFIXES, splat_format

VIDEO_SUFFIXES = (".mp4", ".gif")
IMAGE_SUFFIXES = (".png",)
SUPPORTED_SUFFIXES = VIDEO_SUFFIXES + IMAGE_SUFFIXES


# ----------------------------------------------------------------------------- destination checks
def check_destination(out_path, *, suffixes=SUPPORTED_SUFFIXES, size: tuple[int, int] | None = None) -> Path:
    """Validate ``out_path`` before anything is rendered: a supported suffix, an existing writable
    folder, and (for ``.mp4``) an even frame size. Returns the path."""
    out = Path(out_path)
    suffix = out.suffix.lower()
    if suffix not in suffixes:
        raise ValueError(f"{out}: unsupported output type {suffix or '(no suffix)'!r}; "
                         f"supported: {', '.join(suffixes)}")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"{out}: the output folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{out}: the output folder {folder} is not writable")
    if out.is_dir():
        raise ValueError(f"{out}: is a folder, not a file name")
    if suffix == ".mp4" and size is not None:
        w, h = size
        if w % 2 or h % 2:
            raise ValueError(f"{out}: mp4 (H.264, yuv420p) needs an even frame size, found {w}x{h}")
    return out


# ----------------------------------------------------------------------------- writers
def _to_rgb8(frame: np.ndarray) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        frame = (np.clip(frame, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    if frame.ndim == 3 and frame.shape[2] == 4:
        frame = frame[..., :3]
    return np.ascontiguousarray(frame)


def write_frames(frames: Iterable[np.ndarray], path, fps: float) -> int:
    """Write RGB(A) frames to ``path`` (format by suffix; ``path`` must not need to be atomic).
    Returns the number of frames written."""
    import imageio.v2 as iio2
    import imageio.v3 as iio3

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"{path}: unsupported video type {suffix!r}; supported: {', '.join(VIDEO_SUFFIXES)}")
    if not fps or fps <= 0:
        raise ValueError(f"{path}: fps must be positive, found {fps}")
    count = 0
    if suffix == ".mp4":
        writer = iio2.get_writer(path, format="FFMPEG", mode="I", fps=float(fps), codec="libx264",
                                 pixelformat="yuv420p", macro_block_size=1, quality=None,
                                 output_params=["-crf", "18"], ffmpeg_log_level="error")
        try:
            for frame in frames:
                rgb = _to_rgb8(frame)
                if rgb.shape[0] % 2 or rgb.shape[1] % 2:
                    raise ValueError(f"{path}: mp4 (H.264, yuv420p) needs an even frame size, "
                                     f"found {rgb.shape[1]}x{rgb.shape[0]}")
                writer.append_data(rgb)
                count += 1
        finally:
            writer.close()
    else:  # .gif
        images = [_to_rgb8(f) for f in frames]
        count = len(images)
        if count == 0:
            raise ValueError(f"{path}: no frames to write")
        duration_ms = 1000.0 / float(fps)
        iio3.imwrite(path, np.stack(images), extension=".gif", duration=duration_ms, loop=0)
    if count == 0:
        raise ValueError(f"{path}: no frames to write")
    return count


# ----------------------------------------------------------------------------- snapshots / cameras
def orbit_cameras(snap, frames: int, width: int, height: int, elevation: float = 5.0, fill: float = 0.8,
                  fov_y_deg: float = 30.0) -> list:
    """``frames`` cameras on a full 360° orbit around the snapshot's bounding-box centre, far
    enough that the body fills about ``fill`` of the frame height (and fits the width)."""
    from reconstruct.camera import Camera

    if frames < 1:
        raise ValueError(f"orbit needs at least 1 frame, found {frames}")
    p = np.asarray(snap.means, np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if p.shape[0] == 0:
        raise ValueError("orbit: the avatar has no finite Gaussians to frame")
    lo, hi = p.min(0), p.max(0)
    centre = 0.5 * (lo + hi)
    extent = hi - lo
    body_height = max(float(extent[2]), 1e-3)  # Z up
    horiz_radius = 0.5 * float(np.hypot(extent[0], extent[1]))  # worst case over azimuths
    tan_half = math.tan(math.radians(fov_y_deg) / 2.0)
    # vertical: half height at the distance of the target plane fills `fill` of the half frame;
    # parts nearer than the target plane look bigger, so back off by part of the horizontal radius.
    dist_v = 0.5 * body_height / (fill * tan_half) + 0.5 * horiz_radius
    aspect = width / height
    dist_h = horiz_radius / (fill * tan_half * aspect) + horiz_radius
    distance = max(dist_v, dist_h, 1e-2)
    far = distance + 4.0 * float(np.linalg.norm(extent)) + 1.0
    return [Camera.orbit(360.0 * k / frames, elevation, distance, centre, width=width, height=height,
                         fov_y_deg=fov_y_deg, far=far, name=f"orbit_{k:03d}") for k in range(frames)]


def _even(x: float) -> int:
    return max(2, 2 * round(x / 2.0))


def _fit_camera(camera, size: int | None):
    """``camera`` scaled so that its longer side is ``size`` (other side rounded to even)."""
    if size is None:
        return camera
    if size < 2:
        raise ValueError(f"size must be at least 2 pixels, found {size}")
    w, h = camera.width, camera.height
    if w >= h:
        nw, nh = int(size), _even(size * h / w)
    else:
        nw, nh = _even(size * w / h), int(size)
    return camera.scaled(nw, nh)


class _Renderer:
    """An offscreen context and a SplatRenderer, released on exit."""

    def __enter__(self):
        from renderer.gl_context import create_offscreen_context
        from renderer.splat_renderer import SplatRenderer

        self.ctx = create_offscreen_context()
        try:
            self.renderer = SplatRenderer(self.ctx)
        except BaseException:
            self.ctx.release()
            raise
        return self.renderer

    def __exit__(self, *exc):
        try:
            self.renderer.release()
        finally:
            self.ctx.release()


def _render(renderer, camera, mode, background):
    return renderer.render(camera, mode=mode, background=background, dtype=np.uint8)


def _progress(iterable, total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit="frame", disable=not enabled)


def _check_mode(mode):
    from renderer.render_modes import RenderMode

    return RenderMode.parse(mode)


# ----------------------------------------------------------------------------- plans
@dataclass
class ExportPlan:
    """What a video export draws: frame ``i`` is ``snapshot(i)`` seen by ``cameras[i]``.
    Building a plan checks the destination and settings but renders nothing; the headless
    commands render it offscreen (``render_plan``), the studio on its window's context."""

    out: Path
    cameras: list
    snapshot: Callable[[int], object]
    fps: float
    desc: str

    def __len__(self) -> int:
        return len(self.cameras)


def _check_video_settings(fps, size=None) -> None:
    if not fps or fps <= 0:
        raise ValueError(f"fps must be positive, found {fps}")
    if size is not None and size < 2:
        raise ValueError(f"size must be at least 2 pixels, found {size}")


def plan_orbit(avatar, out_path, *, frames: int = 60, size: int = 512, fps: float = 30, frame_index: int = 0,
               elevation: float = 5.0) -> ExportPlan:
    """A full 360° orbit (``frames`` views) around the avatar posed at ``frame_index``."""
    out = check_destination(out_path, suffixes=VIDEO_SUFFIXES, size=(size, size))
    if frames < 1:
        raise ValueError(f"orbit needs at least 1 frame, found {frames}")
    _check_video_settings(fps, size)
    n = len(avatar.scene.frames)
    if not 0 <= frame_index < n:
        raise ValueError(f"frame {frame_index} is out of range: the scene has {n} frames (0..{n - 1})")
    snap = avatar.make_snapshot("observation", frame_index)
    cameras = orbit_cameras(snap, frames, size, size, elevation=elevation)
    return ExportPlan(out, cameras, lambda i: snap, float(fps), "orbit")


def plan_poses(avatar, out_path, *, scene=None, size: int | None = 512, fps: float | None = None,
               camera=None) -> ExportPlan:
    """One frame per pose of ``scene`` (default the avatar's own) from that frame's training
    camera (or ``camera``), longer side ``size`` pixels, at ``fps`` (default the scene's)."""
    own = scene is None or scene is avatar.scene
    scene = avatar.scene if scene is None else scene
    if not own and scene.body != avatar.scene.body:
        raise ValueError(f"scene {scene.name}: its body model differs from the one the avatar was trained on "
                         f"({avatar.scene.name}); poses cannot be transferred")
    if not scene.frames:
        raise ValueError(f"scene {scene.name}: no frames to export")
    fps = float(scene.fps if fps is None else fps)
    _check_video_settings(fps)
    cams = [_fit_camera(camera if camera is not None else f.camera, size) for f in scene.frames]
    first = cams[0]
    out = check_destination(out_path, suffixes=VIDEO_SUFFIXES, size=(first.width, first.height))
    if out.suffix.lower() == ".gif" and len({(c.width, c.height) for c in cams}) > 1:
        raise ValueError(f"{out}: the scene's cameras differ in image size; pass a camera")
    frames = scene.frames

    def snapshot(i):
        return avatar.make_snapshot("observation", i) if own else avatar.snapshot_at_pose(frames[i].pose, i)

    return ExportPlan(out, cams, snapshot, fps, "poses")


def plan_novel(avatar, out_path, name: str = "walk", *, frames: int = 30, size: int | None = 512,
               fps: float | None = None, camera=None) -> ExportPlan:
    """A novel pose sequence (``reconstruct.body.novel_poses``: walk cycle, arms up) placed where
    the video's first frame stands, seen from its training camera (or ``camera``)."""
    from reconstruct.body.novel_poses import novel_pose_sequence

    fps = float(avatar.scene.fps if fps is None else fps)
    _check_video_settings(fps)
    cam = _fit_camera(camera if camera is not None else avatar.scene.frames[0].camera, size)
    out = check_destination(out_path, suffixes=VIDEO_SUFFIXES, size=(cam.width, cam.height))
    poses = novel_pose_sequence(avatar.body, name, frames, base=avatar.scene.frames[0].pose)
    return ExportPlan(out, [cam] * len(poses), lambda i: avatar.snapshot_at_pose(poses[i], 0), fps, name)


def plan_sequence(avatar, out_path, poses, *, fps: float, desc: str, size: int | None = 512,
                  camera=None) -> ExportPlan:
    """One frame per ``BodyPose`` of ``poses`` (poses of ``avatar.body`` in the scene's world),
    seen from the video's first training camera (or ``camera``)."""
    _check_video_settings(fps)
    if not len(poses):
        raise ValueError(f"{desc}: no poses to export")
    cam = _fit_camera(camera if camera is not None else avatar.scene.frames[0].camera, size)
    out = check_destination(out_path, suffixes=VIDEO_SUFFIXES, size=(cam.width, cam.height))
    return ExportPlan(out, [cam] * len(poses), lambda i: avatar.snapshot_at_pose(poses[i], 0), float(fps), desc)


def plan_motion(avatar, out_path, motion: MotionPoses, *, size: int | None = 512, camera=None) -> ExportPlan:
    """A motion file retargeted onto the avatar (``motion_poses``), at its (resampled) frame rate."""
    return plan_sequence(avatar, out_path, motion.poses, fps=motion.fps, desc=motion.path.name, size=size,
                         camera=camera)


def render_plan(plan: ExportPlan, *, mode="rgb", background=(0, 0, 0), progress: bool = True) -> Path:
    """Render ``plan`` offscreen (EGL) and write it atomically. Returns the path."""
    mode = _check_mode(mode)
    with _Renderer() as renderer:
        def images():
            for i, cam in _progress(enumerate(plan.cameras), len(plan), plan.desc, progress):
                renderer.set_snapshot(plan.snapshot(i))
                yield _render(renderer, cam, mode, background)

        with atomic_output(plan.out) as tmp:
            write_frames(images(), tmp, plan.fps)
    return plan.out


# ----------------------------------------------------------------------------- motion files
@dataclass(frozen=True)
class MotionPoses:
    """A motion file retargeted onto an avatar's body (``reconstruct.motion``): one ``BodyPose`` per
    frame at ``fps``, placed on the video's first frame and grounded on the video's floor.
    ``notes``: what the retargeting detected, assumed and dropped (show them to the user)."""

    path: Path
    poses: list
    fps: float
    notes: tuple[str, ...] = ()
    dropped: tuple[str, ...] = ()
    source_frames: int = 0
    source_fps: float = 0.0

    def __len__(self) -> int:
        return len(self.poses)


def check_motion_times(start: float | None, end: float | None) -> None:
    """``start``/``end`` (seconds into the file) before anything is read."""
    for name, v in (("start", start), ("end", end)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise ValueError(f"--{name} must be a non-negative number of seconds, found {v}")
    if start is not None and end is not None and end <= start:
        raise ValueError(f"--end {end:g} s must be after --start {start:g} s")


def read_motion(path):
    """``reconstruct.motion.load_motion``: a ``MotionClip``, or ``MotionFileError`` (a ValueError)
    naming the file and what is wrong with it."""
    from reconstruct.motion import load_motion

    return load_motion(path)


def retarget_motion(motion, body, scene, *, fps: float | None = None, start: float | None = None,
                    end: float | None = None, loop: bool = False) -> MotionPoses:
    """``motion`` (a file path or a ``MotionClip``) retargeted onto ``body`` (the avatar's), starting
    where ``scene``'s first frame stands, the feet on the floor of the scene's poses, resampled to
    ``fps`` (default: the scene's, the frame rate exports use)."""
    from reconstruct.motion import MotionClip, retarget

    clip = motion if isinstance(motion, MotionClip) else read_motion(motion)
    fps = float(scene.fps if fps is None else fps)
    _check_video_settings(fps)
    check_motion_times(start, end)
    try:
        result = retarget(clip, body, fps=fps, start=start, end=end, loop=loop,
                          base_pose=scene.frames[0].pose, floor_poses=[f.pose for f in scene.frames])
    except ValueError as exc:
        raise ValueError(f"{clip.source}: {exc}") from exc
    if not result.poses:
        raise ValueError(f"{clip.source}: no frames between start and end")
    return MotionPoses(Path(clip.source), list(result.poses), float(result.fps), tuple(result.notes),
                       tuple(result.dropped), clip.num_frames, float(clip.fps))


def motion_poses(avatar, motion, *, fps: float | None = None, start: float | None = None,
                 end: float | None = None, loop: bool = False) -> MotionPoses:
    """``retarget_motion`` onto a ``TrainedAvatar``'s body and scene."""
    return retarget_motion(motion, avatar.body, avatar.scene, fps=fps, start=start, end=end, loop=loop)


# ----------------------------------------------------------------------------- .ply (3DGS)
@dataclass
class PlyPlan:
    """What a ``.ply`` export writes: ``snapshot(i)`` for each of ``count`` frames, into the file
    ``out`` (``sequence`` False, one frame) or into the folder ``out`` as ``frame_0000.ply`` ...
    Building a plan checks the destination and settings and poses nothing."""

    out: Path
    count: int
    snapshot: Callable[[int], object]
    sequence: bool
    desc: str

    def __len__(self) -> int:
        return self.count


def check_ply_destination(out_path, *, sequence: bool, overwrite: bool = False) -> Path:
    """A splat file name (``.ply``, ``.compressed.ply``, ``.splat``, ``.spz``, ``.sog``) in a writable folder,
    or (``sequence``) a new folder name there."""
    out = Path(out_path)
    if not sequence:
        return check_destination(out, suffixes=GAUSSIAN_SUFFIXES)  # the name picks the layout
    if out.suffix.lower() in GAUSSIAN_SUFFIXES:
        raise ValueError(f"{out}: a pose sequence is written as one file per frame into a folder; "
                         f"give a folder name (without {out.suffix})")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"{out}: the output folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{out}: the output folder {folder} is not writable")
    if out.exists() and not (overwrite and out.is_dir()):
        what = "a file" if not out.is_dir() else "a folder (pass --overwrite to replace the sequence in it)"
        raise ValueError(f"{out}: already exists and is {what}")
    return out


def plan_ply(avatar, out_path, *, frame: int | None = None, canonical: bool = False, novel: str | None = None,
             frames: int = 30, motion: MotionPoses | None = None, scene=None, overwrite: bool = False) -> PlyPlan:
    """The avatar's Gaussians: at video frame ``frame`` (default 0) or in the ``canonical`` space
    (one file), or a sequence (one file per frame into a folder): a ``novel`` pose sequence of
    ``frames`` frames, a retargeted ``motion``, or the poses of ``scene`` (the avatar's own or
    another with the same body)."""
    chosen = [k for k, v in (("frame", frame is not None), ("canonical", canonical), ("novel", novel),
                             ("motion", motion is not None), ("poses", scene is not None)) if v]
    if len(chosen) > 1:
        raise ValueError(f".ply export: choose one of frame, canonical, novel, motion, poses; found {chosen}")
    what = chosen[0] if chosen else "frame"
    n = len(avatar.scene.frames)
    if what == "frame":
        f = 0 if frame is None else int(frame)
        if not 0 <= f < n:
            raise ValueError(f"frame {f} is out of range: the scene has {n} frames (0..{n - 1})")
        out = check_ply_destination(out_path, sequence=False)
        return PlyPlan(out, 1, lambda i: avatar.make_snapshot("observation", f), False, f"frame {f}")
    if what == "canonical":
        out = check_ply_destination(out_path, sequence=False)
        return PlyPlan(out, 1, lambda i: avatar.make_snapshot("canonical", 0), False, "canonical")
    out = check_ply_destination(out_path, sequence=True, overwrite=overwrite)
    if what == "novel":
        from reconstruct.body.novel_poses import NOVEL_POSES, novel_pose_sequence

        if novel not in NOVEL_POSES:
            raise ValueError(f"novel pose sequence {novel!r}: choose one of {', '.join(NOVEL_POSES)}")
        if frames < 2:
            raise ValueError(f"a novel pose sequence needs at least 2 frames, found {frames}")
        poses = novel_pose_sequence(avatar.body, novel, frames, base=avatar.scene.frames[0].pose)
        return PlyPlan(out, len(poses), lambda i: avatar.snapshot_at_pose(poses[i], 0), True, novel)
    if what == "motion":
        poses = motion.poses
        return PlyPlan(out, len(poses), lambda i: avatar.snapshot_at_pose(poses[i], 0), True, motion.path.name)
    own = scene is avatar.scene
    if not own and scene.body != avatar.scene.body:
        raise ValueError(f"scene {scene.name}: its body model differs from the one the avatar was trained on "
                         f"({avatar.scene.name}); poses cannot be transferred")
    if not scene.frames:
        raise ValueError(f"scene {scene.name}: no frames to export")
    frames_ = scene.frames

    def snapshot(i):
        return avatar.make_snapshot("observation", i) if own else avatar.snapshot_at_pose(frames_[i].pose, i)

    return PlyPlan(out, len(frames_), snapshot, True, "poses")


class _LazySnapshots:
    """``plan.snapshot(i)`` for each frame, posed only when iterated (one at a time)."""

    def __init__(self, plan: PlyPlan) -> None:
        self.plan = plan

    def __len__(self) -> int:
        return len(self.plan)

    def __iter__(self):
        return (self.plan.snapshot(i) for i in range(len(self.plan)))


def check_splat_format(out_path, fmt: str | None, *, sequence: bool) -> None:
    """ValueError for a ``fmt`` that is not a splat layout, or that disagrees with a single file's
    name (which picks its own layout)."""
    if fmt is None:
        return
    if fmt not in SPLAT_FORMATS:
        raise ValueError(f"splat file format must be one of {', '.join(SPLAT_FORMATS)}, found {fmt!r}")
    if not sequence and splat_format(out_path) != fmt:
        raise ValueError(f"{out_path}: the name asks for {splat_format(out_path)!r}, the format given is {fmt!r}; "
                         f"name the file NAME.{fmt}")


def write_ply_plan(plan: PlyPlan, *, up: str = "y_down", sh_degree: int = 3, progress: bool | Callable = True,
                   overwrite: bool = False, fmt: str | None = None) -> Path:
    """Write ``plan`` (``reconstruct.ply``: atomically, a sequence all or nothing). ``fmt``: the
    layout of a sequence's files ("ply" by default, "compressed.ply", "splat", "spz", "sog"; a single
    file's name picks its own, and a ``fmt`` that disagrees with it is an error). ``progress``:
    a tqdm bar (True), none (False), or a ``progress(done, total)`` callable. Returns ``plan.out``."""
    from reconstruct.ply import UP_CHOICES, write_ply_sequence, write_snapshot_ply

    check_splat_format(plan.out, fmt, sequence=plan.sequence)
    if up not in UP_CHOICES:
        raise ValueError(f"up must be one of {', '.join(UP_CHOICES)}, found {up!r}")
    if sh_degree not in (0, 1, 2, 3):
        raise ValueError(f"sh_degree must be 0, 1, 2 or 3, found {sh_degree}")
    if not plan.sequence:
        write_snapshot_ply(plan.out, plan.snapshot(0), up=up, sh_degree=sh_degree)
        if callable(progress):
            progress(1, 1)
        return plan.out
    bar = None
    if callable(progress):
        callback = progress
    else:
        from tqdm import tqdm

        bar = tqdm(total=len(plan), desc=f"{plan.desc} .ply", unit="frame", disable=not progress)
        callback = lambda done, total: bar.update(done - bar.n)
    try:
        write_ply_sequence(plan.out, _LazySnapshots(plan), progress=callback, overwrite=overwrite, up=up,
                           sh_degree=sh_degree, suffix="." + (fmt or "ply"))
    finally:
        if bar is not None:
            bar.close()
    return plan.out


# ----------------------------------------------------------------------------- public API
def export_orbit(avatar, out_path, *, frames: int = 60, size: int = 512, fps: float = 30, frame_index: int = 0,
                 elevation: float = 5.0, mode="rgb", background=(0, 0, 0), progress: bool = True) -> Path:
    """A full 360° orbit (``frames`` views) around the avatar posed at ``frame_index``, written to
    ``out_path`` (``.mp4`` or ``.gif``) at ``fps``. Returns the path."""
    check_destination(out_path, suffixes=VIDEO_SUFFIXES, size=(size, size))
    mode = _check_mode(mode)
    plan = plan_orbit(avatar, out_path, frames=frames, size=size, fps=fps, frame_index=frame_index,
                      elevation=elevation)
    return render_plan(plan, mode=mode, background=background, progress=progress)


def export_poses(avatar, out_path, *, scene=None, size: int | None = 512, fps: float | None = None, camera=None,
                 mode="rgb", background=(0, 0, 0), progress: bool = True) -> Path:
    """One frame per pose of ``scene`` (default the avatar's own scene) seen from that frame's
    training camera (or the given ``camera``), longer side ``size`` pixels (None: the camera's
    size), at ``fps`` (default the scene's). Returns the path."""
    mode = _check_mode(mode)
    plan = plan_poses(avatar, out_path, scene=scene, size=size, fps=fps, camera=camera)
    return render_plan(plan, mode=mode, background=background, progress=progress)


def export_novel(avatar, out_path, name: str = "walk", *, frames: int = 30, size: int | None = 512,
                 fps: float | None = None, camera=None, mode="rgb", background=(0, 0, 0),
                 progress: bool = True) -> Path:
    """A novel pose sequence (walk cycle, arms up) of ``frames`` frames; see ``plan_novel``."""
    mode = _check_mode(mode)
    plan = plan_novel(avatar, out_path, name, frames=frames, size=size, fps=fps, camera=camera)
    return render_plan(plan, mode=mode, background=background, progress=progress)


def export_motion(avatar, out_path, motion, *, fps: float | None = None, start: float | None = None,
                  end: float | None = None, loop: bool = False, size: int | None = 512, camera=None, mode="rgb",
                  background=(0, 0, 0), progress: bool = True) -> Path:
    """A motion file (``.bvh``, ``.fbx``, ``.glb`` / ``.gltf``, SMPL-family ``.npz``; or ``MotionPoses``
    already retargeted) performed by the avatar, from the video's first training camera; see
    ``motion_poses``."""
    mode = _check_mode(mode)
    check_destination(out_path, suffixes=VIDEO_SUFFIXES)
    if not isinstance(motion, MotionPoses):
        motion = motion_poses(avatar, motion, fps=fps, start=start, end=end, loop=loop)
    plan = plan_motion(avatar, out_path, motion, size=size, camera=camera)
    return render_plan(plan, mode=mode, background=background, progress=progress)


def export_ply(avatar, out_path, *, up: str = "y_down", sh_degree: int = 3, progress: bool = True,
               overwrite: bool = False, **what) -> Path:
    """The avatar's Gaussians as 3DGS ``.ply``: one file or a folder of frames; ``what`` as
    ``plan_ply`` (frame=, canonical=, novel= and frames=, motion=, scene=)."""
    plan = plan_ply(avatar, out_path, overwrite=overwrite, **what)
    return write_ply_plan(plan, up=up, sh_degree=sh_degree, progress=progress, overwrite=overwrite)


def export_screenshot(avatar, out_path, camera=None, *, frame_index: int = 0, size: int | None = None,
                      mode="rgb", background=(0, 0, 0), transparent: bool = False) -> Path:
    """One ``.png`` of the avatar posed at ``frame_index`` seen by ``camera`` (default: that
    frame's training camera), RGB, or RGBA with ``transparent``."""
    n = len(avatar.scene.frames)
    if not 0 <= frame_index < n:
        raise ValueError(f"frame {frame_index} is out of range: the scene has {n} frames (0..{n - 1})")
    out = check_destination(out_path, suffixes=IMAGE_SUFFIXES)
    mode = _check_mode(mode)
    cam = _fit_camera(camera if camera is not None else avatar.scene.frames[frame_index].camera, size)
    snap = avatar.make_snapshot("observation", frame_index)
    with _Renderer() as renderer:
        renderer.set_snapshot(snap)
        img = renderer.render(cam, mode=mode, background=None if transparent else background, dtype=np.uint8)
    with atomic_output(out) as tmp:
        import imageio.v3 as iio3

        iio3.imwrite(tmp, np.ascontiguousarray(img if transparent else img[..., :3]), extension=".png")
    return out


def export(avatar, out_path, **kwargs) -> Path:
    """Dispatch by suffix: ``.png`` -> screenshot, ``.mp4``/``.gif`` -> orbit (or poses with
    ``poses=True``, or a novel pose sequence with ``novel="walk"``)."""
    suffix = Path(out_path).suffix.lower()
    if suffix in IMAGE_SUFFIXES:
        return export_screenshot(avatar, out_path, **kwargs)
    if suffix in VIDEO_SUFFIXES:
        novel = kwargs.pop("novel", None)
        if novel:
            return export_novel(avatar, out_path, novel, **kwargs)
        if kwargs.pop("poses", False):
            return export_poses(avatar, out_path, **kwargs)
        return export_orbit(avatar, out_path, **kwargs)
    raise ValueError(f"{out_path}: unsupported output type {suffix or '(no suffix)'!r}; "
                     f"supported: {', '.join(SUPPORTED_SUFFIXES)}")
