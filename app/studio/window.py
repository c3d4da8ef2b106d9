"""The studio window: glfw (OpenGL 3.3 core) + imgui-bundle's native glfw/opengl3 backends (and
implot) + moderngl on the same context. The SplatRenderer draws the trainer's latest snapshot
into an offscreen framebuffer (viewport.py: only when the snapshot, the edit selection's highlight,
camera, mode or size changed) that is blitted to the window every frame; the imgui panels are
drawn on top. The editor (selection tools, highlight, edit requests) is ``EditController``
(edit_controller.py, edit_input.py, edit_tools.py; docs/editing.md).

Threads: the GL thread (this loop) only reads the trainer thread's latest snapshot and status and
calls its action methods; the trainer thread steps the trainer and applies the actions between
steps; an export runs in its own worker thread and has its frames rendered here, one per GUI frame.

Shape: ``ViewState`` (what is shown) and the panels (``panels/``, one file each, given a
``PanelContext``) on one side; ``StudioApp`` implements the panels' actions and draws one frame;
``FramePacer`` decides when (``pacing.py``); ``run_studio`` sets up and tears down.

``run_studio(..., script=f)`` calls ``f(app)`` every frame so that tests can watch (or drive) the
GUI state; ``rects_path`` writes the screen rectangles of the widgets the GUI test clicks."""

from __future__ import annotations

import ctypes
import json
import os
import sys
import threading
import time
import traceback
import warnings
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from imgui_bundle import (
    imgui,  # before glfw: imgui-bundle points pyglfw at its own libglfw (DESIGN.md)
    implot,
)

# isort: split
import glfw

from renderer.render_modes import RenderMode

from . import edit_input, panels
from .drops import DropQueue, drop_kind, not_taken
from .edit_controller import EditController
from .export_job import ExportJob, ExportPanelState
from .footage import FootageController
from .jobs import take_finished
from .layout import STUDIO_PANELS, draw_panels
from .orbit_input import apply_mouse
from .pacing import FramePacer
from .panels.stage2 import default_settings
from .trainer_thread import TrainerThread
from .view_state import POSE_SOURCES, ViewState
from .viewport import GroundTruthImage, SplatView
from .viewport import to_rgb8 as _to_rgb8

NO_DISPLAY_MESSAGE = ("wonderhuman-studio: no display to open the studio window on (DISPLAY/WAYLAND_DISPLAY unset "
                      "or the window could not open); headless: `wonderhuman-studio demo`, `train` or `export`")
SCENE_ERROR_RC = 2


class NoDisplayError(RuntimeError):
    pass


def display_available() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def open_window(width: int, height: int, title: str = "WonderHuman Studio"):
    """A glfw window with a current OpenGL 3.3 core context, or NoDisplayError."""
    if not display_available():
        raise NoDisplayError(NO_DISPLAY_MESSAGE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", glfw.GLFWError)
        ok = glfw.init()
    if not ok:
        raise NoDisplayError(NO_DISPLAY_MESSAGE)
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
    win = glfw.create_window(int(width), int(height), title, None, None)
    if not win:
        glfw.terminate()
        raise NoDisplayError(NO_DISPLAY_MESSAGE)
    glfw.make_context_current(win)
    glfw.swap_interval(0)  # the loop paces itself (max_fps / idle_fps)
    return win


class StudioApp:
    """One studio window: the view state, the renderer and the panels' actions. ``script``
    callbacks of ``run_studio`` get this object."""

    def __init__(self, window, ctx, trainer: TrainerThread, pacer: FramePacer | None = None, run_lock=None) -> None:
        from renderer.orbit_camera import OrbitCamera
        from renderer.splat_renderer import SplatRenderer

        self.window = window
        self.drops = DropQueue()
        self.drops.install(glfw, window)
        self.ctx = ctx
        self.trainer = trainer
        self.run_lock = run_lock  # the run folder's lock while the window trains into it
        self.pacer = pacer or FramePacer()
        self.scene = trainer.trainer.scene
        self.background = tuple(float(c) for c in trainer.trainer.config.background)
        self.renderer = SplatRenderer(ctx, target_dtype="f4")
        self.orbit = OrbitCamera()
        self.orbit.snap_to(self.scene.frames[0].camera)
        self.footage = FootageController(self)
        self._textures: dict[str, object] = {}
        self._framed = False
        self.view = ViewState()
        self._play_clock = time.perf_counter()
        self.frame_count = 0
        self.should_close = False
        self._screenshots: list[Path] = []
        self.splat_view = SplatView(ctx, self.renderer)  # the splats' cached framebuffer (viewport.py)
        self.gt_image = GroundTruthImage(ctx)
        self.last_drawn_snapshot = None  # (version, space, frame_index, step) of what is on screen
        self.rects: dict[str, list[float]] = {}
        self._fb_size, self._fb_size_frame = (0, 0), -1
        self.cache: dict = {}  # panels' per-frame caches (plot arrays, curves)
        self.stage2_settings = default_settings()  # as the Stage II panel shows them
        self.trainer.set_stage2_settings(self.stage2_settings)
        self.export = ExportPanelState()
        self.saved_on_close: str | None = None
        self._beside_key = None
        self._beside_snap = None
        self._frame_beside = False
        self.edits = EditController(self)  # selection tools, highlight, edits through the trainer's queue
        self.drawn_view = None  # (camera, avatar snapshot) of the last splat render: what strokes select on

    # ----- what scripts and tests read -------------------------------------------------------
    @property
    def status(self):
        return self.trainer.status()

    def latest_snapshot(self):
        return self.trainer.latest_snapshot()

    @property
    def fps(self) -> float:
        return self.pacer.fps

    @property
    def num_pose_frames(self) -> int:
        key = self.sequence_key
        return self.trainer.sequence_length(key) if key else len(self.scene.frames)

    @property
    def sequence_key(self) -> str:
        """The trainer thread's name of the pose sequence shown ("" for the video's poses)."""
        source = self.view.pose_source
        if source == "video":
            return ""
        if source == "motion":
            loaded = self.view.motion.loaded
            return loaded.key if loaded is not None else ""
        return source

    @property
    def pose_fps(self) -> float:
        """Frame rate of what the Pose panel plays (a motion file is resampled to the scene's)."""
        loaded = self.view.motion.loaded
        return loaded.fps if self.view.pose_source == "motion" and loaded is not None else float(self.scene.fps)

    @property
    def exporting(self) -> bool:
        return self.export.job is not None and not self.export.job.done

    @property
    def busy(self) -> bool:
        """Something moves without input: playback, an export, a motion file being read, footage
        being prepared."""
        return (self.view.playing or self.exporting or self.view.motion.loading or self.view.beside.loading
                or self.footage.busy or self.edits.busy)

    def attach_trainer(self, trainer, run_folder=None, run_lock=None) -> None:
        """Show and train ``trainer`` from now on (the footage panel's "Train on it": the previous
        trainer thread was stopped and its lock released off the GL thread)."""
        thread = TrainerThread(trainer, run_folder=run_folder, publish_every=self.trainer.publish_every)
        self.trainer, self.run_lock = thread, run_lock
        self.scene = trainer.scene
        self.background = tuple(float(c) for c in trainer.config.background)
        self.view = ViewState()
        self.edits = EditController(self)
        self.drawn_view = None
        self.cache.clear()
        self._framed = False
        self.gt_image.forget()
        self.orbit.snap_to(self.scene.frames[0].camera)
        thread.set_stage2_settings(self.stage2_settings)
        thread.start()

    def texture(self, path: str):
        """A GL texture of the image at ``path`` (read once; None when unreadable)."""
        if path not in self._textures:
            try:
                import imageio.v3 as iio

                rgb = _to_rgb8(iio.imread(path))
                tex = self.ctx.texture((rgb.shape[1], rgb.shape[0]), 3, rgb.tobytes())
            except (OSError, ValueError):
                tex = None
            self._textures[path] = tex
        return self._textures[path]

    # ----- actions (the panels call these; so may scripts) -------------------------------------
    def pause(self, paused: bool = True) -> None:
        self.trainer.pause(paused)

    def single_step(self) -> None:
        self.trainer.single_step()

    def save_checkpoint(self) -> None:
        self.trainer.request_save()

    def start_stage2(self) -> None:
        self.trainer.start_stage2()

    def push_stage2_settings(self, **changes) -> None:
        """Hand the Stage II settings to the trainer (applied between steps)."""
        self.stage2_settings.update(changes)
        self.trainer.set_stage2_settings(self.stage2_settings)

    def set_mode(self, mode) -> None:
        self.view.mode = RenderMode.parse(mode)

    def _push_view(self) -> None:
        v = self.view
        self.trainer.set_view(space=v.space, frame_index=v.frame_index, novel=self.sequence_key,
                              novel_index=v.novel_index)

    def set_space(self, space: str) -> None:
        if space not in ("observation", "canonical"):
            raise ValueError(f"space must be observation or canonical, found {space!r}")
        self.view.space = space
        self._framed = False  # re-centre the orbit pivot on the next snapshot
        self._push_view()

    def set_frame(self, i: int) -> None:
        self.view.frame_index = int(i) % len(self.scene.frames)
        self._push_view()

    def set_pose_source(self, source: str) -> None:
        if source not in POSE_SOURCES:
            raise ValueError(f"unknown pose source {source!r}; choose one of {POSE_SOURCES}")
        if source == "motion" and self.view.motion.loaded is None:
            self.view.motion.message = "no motion file open yet: type its path below and press Open"
            return
        self.view.pose_source = source
        self.view.novel_index = 0
        if source != "video":
            self.view.space = "observation"
        self._push_view()

    def set_pose_frame(self, i: int) -> None:
        if self.view.pose_source == "video":
            self.set_frame(i)
        else:
            self.view.novel_index = int(i) % max(1, self.num_pose_frames)
            self._push_view()

    def toggle_play(self) -> None:
        self.view.playing = not self.view.playing

    def open_motion(self, path=None, loop: bool | None = None) -> bool:
        """Read a motion file (``path``, default the Pose panel's field) and retarget it onto the
        avatar in a background thread; when it is ready (``poll_motion``) the live view shows it.
        A failure is shown in the Pose panel; the motion shown before stays. Returns whether a load
        started."""
        from .motion_source import start_motion_load

        m = self.view.motion
        if path is not None:
            m.path = str(path)
        if loop is not None:
            m.loop = bool(loop)
        if m.loading:
            m.message = "a motion file is being read; wait for it"
            return False
        start_motion_load(m, self.trainer.trainer.state.body, self.scene)
        return True

    def poll_motion(self) -> None:
        """GL thread, once a frame: take a finished motion load (never waits)."""
        m = self.view.motion
        job = take_finished(m, "the motion file")
        if job is None:
            return
        loaded, previous = job.result, m.loaded
        self.trainer.add_pose_sequence(loaded.key, loaded.poses)
        m.loaded, m.message = loaded, None
        self.view.pose_source = "motion"
        self.view.space = "observation"
        self.view.novel_index = 0
        self.view.gt_view = None
        self._push_view()
        if previous is not None:
            self.trainer.remove_pose_sequence(previous.key)

    def snap_to_training_camera(self) -> None:
        self.view.gt_view = None
        self.orbit.snap_to(self.scene.frames[self.view.frame_index].camera, pivot=self._pivot())

    def snap_to_eval_view(self, k: int) -> None:
        v = self.scene.eval_views[k]
        self.view.pose_source = "video"
        self.view.space = "observation"
        self.view.frame_index = v.frame_index
        self._push_view()
        self.view.gt_view = k
        self.orbit.snap_to(v.camera, pivot=self._pivot())

    def frame_avatar(self) -> None:
        snap = self.latest_snapshot()
        if len(snap):
            self.orbit.look_at_bounds(snap.means)

    def _pivot(self):
        snap = self.latest_snapshot()
        return snap.means.mean(0) if len(snap) else None

    def request_screenshot(self, path) -> None:
        self._screenshots.append(Path(path))

    def screenshot_path(self) -> str:
        return str(Path("exports") / f"studio_{time.strftime('%Y%m%d_%H%M%S')}_{self.frame_count:05d}.png")

    def start_export(self) -> ExportJob | None:
        """Start exporting the export panel's settings (mode: the live view's). An unwritable path
        or a bad setting is refused at once with a message; training goes on either way."""
        from reconstruct.train.trainer import Trainer

        ex = self.export
        if self.exporting:
            ex.message = "an export is already running"
            return None
        e = ex.settings
        e.mode = self.view.mode.value
        e.frame_index = self.view.frame_index
        e.sequence = self.view.pose_source  # what a .ply sequence holds: the Pose panel's poses
        loaded = self.view.motion.loaded
        e.motion_poses = loaded.poses if loaded is not None else None
        e.motion_name = loaded.name if loaded is not None else None
        e.motion_fps = loaded.fps if loaded is not None else None
        try:
            e.validate()
        except (OSError, ValueError) as exc:
            ex.message = f"cannot export: {exc}"
            print(f"wonderhuman-studio: {ex.message}", file=sys.stderr)
            return None
        ex.message = None
        ex.job = ExportJob(e.__class__(**vars(e)), self.trainer.call_between_steps(Trainer.frozen),
                           background=self.background)
        return ex.job

    def cancel_export(self) -> None:
        if self.export.job is not None:
            self.export.job.cancel()

    def open_beside_ply(self, path=None) -> bool:
        """Read a 3DGS .ply (``path``, default the Beside panel's field) in the background and draw
        it beside the live avatar when read; a file that cannot be read is a message in the panel."""
        f = self.view.beside
        if f.loading:
            f.message = "a file is being read; wait for it"
            return False
        f.start(path)
        return True

    def handle_drops(self, paths=None) -> None:
        """Files dropped on the window (``paths``, default the queue): a motion file opens in the Pose
        panel, a splat file beside the avatar; anything else is a message in the Beside panel."""
        for path in self.drops.take() if paths is None else paths:
            kind = drop_kind(path)
            if kind == "motion":
                self.open_motion(path)
            elif kind == "splat":
                self.view.show_beside = True
                self.open_beside_ply(path)
            else:
                self.view.beside.message = not_taken(path)

    def clear_beside_ply(self) -> None:
        self.view.beside.loaded = None
        self.view.beside.message = None

    def poll_beside(self) -> None:
        f = self.view.beside
        job = take_finished(f, "the .ply")
        if job is None:
            return
        f.loaded, f.message = job.result, None
        self.view.show_beside = True
        self._frame_beside = True  # frame the avatar and the file together on the next draw

    def drawn_snapshot(self):
        """What the view draws: the latest snapshot, with the Beside panel's .ply next to it."""
        from .ply_source import place_beside

        snap = self.latest_snapshot()
        other = self.view.beside.loaded
        if other is None or not self.view.show_beside:
            return snap
        key = (id(snap), snap.version, id(other))
        if self._beside_key != key:
            self._beside_key, self._beside_snap = key, place_beside(snap, other.snapshot)
        return self._beside_snap

    def close(self) -> None:
        self.should_close = True

    def mark(self, name: str) -> None:
        """Record the last widget's screen rectangle [x0, y0, x1, y1] (for GUI tests)."""
        a, b = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        self.rects[name] = [round(a.x, 1), round(a.y, 1), round(b.x, 1), round(b.y, 1)]

    # ----- per frame -----------------------------------------------------------------------------
    def panel_context(self) -> panels.PanelContext:
        return panels.PanelContext(view=self.view, status=self.status, actions=self, scene=self.scene,
                                   history=self.trainer.history, history_len=self.trainer.history_len,
                                   stage2_settings=self.stage2_settings, export=self.export,
                                   num_pose_frames=self.num_pose_frames, fps=self.fps, cache=self.cache,
                                   mark=self.mark, footage=self.footage, texture=self.texture, edits=self.edits)

    def change_key(self) -> tuple:
        """What an idle window would show differently: new training values, snapshot, messages."""
        st = self.status
        m, b = self.view.motion, self.view.beside
        return (self.trainer.history_len, self.latest_snapshot().version, st.stage, st.error, st.stage2_message,
                st.last_saved, st.paused, m.loading, m.message, m.loaded is not None and m.loaded.key, b.loading,
                b.message, id(b.loaded), self.view.show_beside, self.view.edit_panel, self.edits.change_key())

    def pump_export(self) -> None:
        job = self.export.job
        if job is None:
            return
        job.pump(self.ctx)
        if job.done and job.error and self.export.message is None:
            self.export.message = f"export failed: {job.error}"
            print(f"wonderhuman-studio: {self.export.message}", file=sys.stderr)

    def handle_input(self) -> None:
        """Mouse and keys: a selection tool's strokes (its left drags do not orbit), the orbit,
        H (panels), Ctrl+Z / Ctrl+Shift+Z (edits)."""
        _, fh, vw, vh = self.view_size()
        tool_has_left = edit_input.handle_mouse(self.edits, (vw, vh))
        if apply_mouse(edit_input.NoLeftDrag(self.orbit) if tool_has_left else self.orbit, self.pacer, fh):
            self.view.show_gui = not self.view.show_gui
        edit_input.handle_keys(self.edits)

    def advance_playback(self) -> None:
        now = time.perf_counter()
        if not self.view.playing:
            self._play_clock = now
            return
        period = 1.0 / max(1e-3, self.pose_fps)
        if now - self._play_clock >= period:
            self._play_clock = now
            current = self.view.frame_index if self.view.pose_source == "video" else self.view.novel_index
            self.set_pose_frame(current + 1)

    def _ground_truth(self) -> np.ndarray | None:
        v = self.view
        if v.gt_view is not None and v.gt_view < len(self.scene.eval_views):
            return self.scene.eval_views[v.gt_view].image
        if v.pose_source != "video" or v.space != "observation":
            return None
        return self.scene.frames[v.frame_index].image

    def framebuffer_size(self) -> tuple[int, int]:
        """The window's framebuffer size, asked of glfw once per frame (an X round trip)."""
        if self._fb_size_frame != self.frame_count:
            self._fb_size = tuple(glfw.get_framebuffer_size(self.window))
            self._fb_size_frame = self.frame_count
        return self._fb_size

    def view_size(self) -> tuple[int, int, int, int]:
        """(window width, height, splat view width, height): the left half with ground truth."""
        fw, fh = self.framebuffer_size()
        side = self.view.show_ground_truth and self._ground_truth() is not None
        return fw, fh, (max(1, fw // 2) if side else fw), fh

    def draw_ground_truth(self) -> None:
        """The ground-truth image in the right half, aspect kept."""
        if self.view.show_ground_truth:
            fw, fh, vw, _ = self.view_size()
            self.gt_image.draw(self._ground_truth(), (fw, fh), vw)

    def draw_scene(self) -> None:
        """Splats (with the selection highlighted) into the cached offscreen framebuffer when anything
        changed (viewport.SplatView), then copied to the window."""
        fw, fh, vw, vh = self.view_size()
        if fw <= 0 or fh <= 0:
            return
        avatar = self.latest_snapshot()
        snap = self.edits.highlighted(self.drawn_snapshot(), avatar)
        if self._frame_beside and len(snap):
            self.orbit.look_at_bounds(snap.means)
            self._frame_beside = False
        if not self._framed and len(snap):
            self.orbit.snap_to(self.scene.frames[0].camera, pivot=snap.means.mean(0)) if snap.space == "observation" \
                else self.orbit.look_at_bounds(snap.means)
            self._framed = True
        cam = self.orbit.to_camera(vw, vh)
        mode = self.view.mode
        background = self.background if mode is RenderMode.RGB else (0.12, 0.12, 0.14)
        if self.splat_view.draw(snap, cam, mode, background):
            self.last_drawn_snapshot = (snap.version, snap.space, snap.frame_index, snap.step)
            self.drawn_view = (cam, avatar)
        self.splat_view.blit((fw, fh))

    def frame(self, script=None, *, screenshot=None, last: bool = False, rects_path=None) -> None:
        """Draw one frame: panels, export frames, splats, screenshots; then swap."""
        imgui.backends.opengl3_new_frame()
        imgui.backends.glfw_new_frame()
        imgui.new_frame()
        if script is not None:
            script(self)
        self.handle_drops()
        self.poll_motion()
        self.poll_beside()
        self.footage.poll()
        self.edits.poll()
        self.handle_input()
        self.advance_playback()
        if self.view.show_gui:
            draw_panels(self.panel_context(), STUDIO_PANELS)
        self.draw_ground_truth()
        edit_input.draw_overlay(self.edits, self.view_size()[2:])
        imgui.render()
        draw_data = imgui.get_draw_data()
        self.pump_export()
        self.draw_scene()
        final = screenshot is not None and (last or self.should_close or glfw.window_should_close(self.window))
        if (self._screenshots or final) and self.splat_view.fbo is not None:
            image = compose_frame(self.ctx, self.framebuffer_size(), draw_data, self.splat_view.fbo)
            for path in self._screenshots + ([Path(screenshot)] if final else []):
                self.save_screenshot(path, image)
        self._screenshots.clear()
        if rects_path is not None and self.frame_count % 5 == 0:
            self.write_rects(rects_path)
        self.ctx.screen.use()
        imgui.backends.opengl3_render_draw_data(draw_data)
        self.frame_count += 1
        glfw.swap_buffers(self.window)
        self.edits.frame_shown()

    def save_screenshot(self, path, image: np.ndarray) -> str:
        from reconstruct.atomic import atomic_output

        path = Path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_output(path) as tmp:
                from PIL import Image

                Image.fromarray(image).save(tmp, format="PNG")
        except OSError as exc:
            self.export.message = f"screenshot not written: {exc}"
            print(f"wonderhuman-studio: {self.export.message}", file=sys.stderr)
            return ""
        self.export.saved_screenshots.append(str(path))
        return str(path)

    def write_rects(self, path) -> None:
        data = {"window": list(self.framebuffer_size()), "rects": self.rects}
        tmp = Path(str(path) + ".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(path)

    def release(self) -> None:
        if self.export.job is not None:
            self.export.job.cancel()
            self.export.job.join(10)
            self.export.job.release()
        self.splat_view.release()
        self.gt_image.release()
        for tex in self._textures.values():
            if tex is not None:
                tex.release()
        self.renderer.release()


def compose_frame(ctx, size, draw_data, fbo=None) -> np.ndarray:
    fw, fh = size
    shot = ctx.simple_framebuffer((fw, fh), components=4)
    try:
        shot.use()
        ctx.clear(0.08, 0.08, 0.09)
        if fbo is not None:
            ctx.copy_framebuffer(shot, fbo)
            shot.use()
        imgui.backends.opengl3_render_draw_data(draw_data)
        data = shot.read(components=3, alignment=1)
    finally:
        ctx.screen.use()
        shot.release()
    return np.frombuffer(data, np.uint8).reshape(fh, fw, 3)[::-1].copy()


def _lower_this_thread(nice: int) -> None:
    """Lower the scheduling priority of the calling thread only (Linux: nice is per thread), so
    that when the CPU is short the trainer thread goes first and the GUI gets fewer frames."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), int(nice))
    except (AttributeError, OSError):
        pass


def _load_font(io, size: float = 15.0) -> None:
    """imgui-bundle's Droid Sans (Latin and Greek: λ_SDS) instead of the bitmap default font."""
    import imgui_bundle

    path = Path(imgui_bundle.__file__).parent / "assets" / "fonts" / "DroidSans.ttf"
    if path.is_file():
        try:
            io.fonts.add_font_from_file_ttf(str(path), size)
        except Exception as exc:  # noqa: BLE001 -- the default font still works
            print(f"wonderhuman-studio: default font kept ({exc})", file=sys.stderr)


def _save_png(path, image) -> None:
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path)


def _error_loop(win, ctx, message: str, *, max_frames, screenshot, max_fps: float, **texts) -> None:
    """The window shows ``message`` until closed (or ``max_frames``)."""
    frames = 0
    period = 1.0 / max(1.0, max_fps)
    while not glfw.window_should_close(win):
        glfw.wait_events_timeout(period)
        imgui.backends.opengl3_new_frame()
        imgui.backends.glfw_new_frame()
        imgui.new_frame()
        quit_ = panels.draw_error_window(message, **texts)
        imgui.render()
        draw_data = imgui.get_draw_data()
        ctx.screen.use()
        ctx.clear(0.08, 0.08, 0.09)
        last = quit_ or (max_frames is not None and frames + 1 >= max_frames)
        if last and screenshot is not None:
            _save_png(screenshot, compose_frame(ctx, glfw.get_framebuffer_size(win), draw_data))
        imgui.backends.opengl3_render_draw_data(draw_data)
        glfw.swap_buffers(win)
        frames += 1
        if last:
            break


def _open_trainer(scene_spec: str, run_dir, config, progress: bool, device: str | None = None):
    """(trainer, run folder or None, its lock or None): a run folder is locked for the window's
    lifetime, so a second trainer on it -- from a window or the command line -- is refused.
    ``device`` as in ``run_folder.placed_on`` (None: the run's or the settings' own)."""
    from reconstruct.data.load import load_scene
    from reconstruct.run_folder import RunFolder, placed_on
    from reconstruct.train.config import Stage1Config
    from reconstruct.train.trainer import Trainer

    if run_dir is None:
        config = placed_on(config or Stage1Config(), device, scene_spec)
        scene = load_scene(scene_spec, progress=progress)
        return Trainer(scene, config, None, scene_spec=scene_spec), None, None
    run = RunFolder(run_dir)
    lock = run.lock()
    lock.__enter__()
    try:
        return run.open(scene_spec, config, progress=progress, device=device), run, lock
    except BaseException:
        lock.release()
        raise


@contextmanager
def gui_window(size=(1280, 800), pacer: FramePacer | None = None, title: str = "WonderHuman Studio"):
    """The window (its GLX context first, before anything could make an EGL one), a moderngl context
    on it, imgui + implot with their glfw/opengl3 backends; all torn down on exit. ``pacer`` watches
    the window's input. Yields ``(window, ctx)``. Raises NoDisplayError without a display."""
    import moderngl

    win = open_window(*size, title=title)
    imgui_ready = False
    try:
        ctx = moderngl.create_context()
        imgui.create_context()
        implot.create_context()
        io = imgui.get_io()
        io.set_ini_filename("")
        imgui.style_colors_dark()
        _load_font(io)
        if pacer is not None:
            pacer.watch(glfw, win)  # before imgui's backend, which chains these callbacks
        imgui.backends.glfw_init_for_opengl(ctypes.cast(win, ctypes.c_void_p).value, True)
        imgui.backends.opengl3_init("#version 330")
        imgui_ready = True
        yield win, ctx
    finally:
        if imgui_ready:
            imgui.backends.opengl3_shutdown()
            imgui.backends.glfw_shutdown()
            implot.destroy_context()
            imgui.destroy_context()
        glfw.destroy_window(win)
        glfw.terminate()


def run_studio(scene_spec: str, run_dir=None, *, config=None, size=(1280, 800), max_frames: int | None = None,
               script: Callable[[StudioApp], None] | None = None, screenshot=None, publish_every: int = 5,
               progress: bool = True, max_fps: float = 30.0, idle_fps: float = 5.0, active_s: float = 1.5,
               idle_refresh_s: float = 1.0, gui_nice: int | None = 10, rects_path=None,
               device: str | None = None) -> int:
    """Open the studio on ``scene_spec`` (training a new avatar, or resuming ``run_dir``'s checkpoint)
    and run until the window closes, ``max_frames`` frames were drawn, or ``script`` calls
    ``app.close()``; closing saves a checkpoint first when there is a run folder. ``screenshot``:
    PNG of the last frame. Returns 0, or 2 when the scene or run could not be opened (the error is
    shown in the window and on stderr). Raises NoDisplayError without a display. ``device``: where
    to train ("cpu" or "cuda"; None: a resumed run's own device, else the settings')."""
    from reconstruct.run_folder import RunLockedError

    pacer = FramePacer(max_fps=max_fps, idle_fps=idle_fps, active_s=active_s, idle_refresh_s=idle_refresh_s)
    with gui_window(size, pacer) as (win, ctx):
        thread = app = lock = None
        try:
            try:
                trainer, run, lock = _open_trainer(scene_spec, run_dir, config, progress, device)
            except Exception as exc:  # noqa: BLE001 -- any failure to open is shown, not a crash
                if isinstance(exc, RunLockedError):
                    what, message = "the run folder", str(exc)
                    texts = {"title": "The run folder is in use",
                             "hint": "Close the other studio or training process, or open another run folder (--run RUN)."}
                else:
                    what, message, texts = "the scene", f"{scene_spec}: {type(exc).__name__}: {exc}", {}
                print(f"wonderhuman-studio: could not open {what} {message}", file=sys.stderr)
                if not isinstance(exc, (ValueError, OSError, RuntimeError, KeyError)):
                    traceback.print_exc()
                _error_loop(win, ctx, message, max_frames=max_frames, screenshot=screenshot, max_fps=max_fps, **texts)
                return SCENE_ERROR_RC
            thread = TrainerThread(trainer, run_folder=run, publish_every=publish_every)
            app = StudioApp(win, ctx, thread, pacer, run_lock=lock)
            thread.start()
            if gui_nice:
                _lower_this_thread(gui_nice)  # after the trainer thread started: it keeps its priority
            while not glfw.window_should_close(win) and not app.should_close:
                if not pacer.wait(glfw.wait_events_timeout, glfw.poll_events, busy=app.busy, changes=app.change_key(),
                                  always=script is not None):
                    continue
                last = max_frames is not None and app.frame_count + 1 >= max_frames
                app.frame(script, screenshot=screenshot, last=last, rects_path=rects_path)
                if last:
                    break
            return 0
        finally:
            if app is not None:  # the footage panel may have switched to another trainer and run folder
                thread, lock = app.trainer, app.run_lock
            if thread is not None:
                running = thread.running and not thread.trainer.done
                thread.stop(save=True)  # a checkpoint first when there is a run folder
                if thread.last_saved and app is not None:
                    app.saved_on_close = thread.last_saved
                    print(f"wonderhuman-studio: {'training stopped; ' if running else ''}saved {thread.last_saved}",
                          file=sys.stderr)
            if lock is not None:
                lock.release()
            if app is not None:
                app.release()
