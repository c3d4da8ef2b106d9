"""Headless export of a trained avatar: 360° orbit videos, pose sequences and screenshots.

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
    return max(2, 2 * int(round(x / 2.0)))


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
