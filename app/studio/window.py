"""The studio window: glfw (OpenGL 3.3 core) + imgui-bundle's native glfw/opengl3 backends (and
implot) + moderngl on the same context. The SplatRenderer draws the trainer's latest snapshot
into an offscreen framebuffer (only when the snapshot, camera, mode or size changed) that is
blitted to the window every frame; the imgui panels are drawn on top.

Threads: the GL thread (this loop) only reads ``trainer.session.snapshots.latest()`` and writes
``Controls``; the trainer thread steps the session and applies the controls between steps; an
export runs in its own worker thread and has its frames rendered here, one per GUI frame.

Frame rate: at most ``max_fps`` while the user interacts (input in the last ``active_s``
seconds), playback runs or an export renders; ``idle_fps`` otherwise. glfw wakes the loop at
once on input, so the GUI answers input at the full rate while an idle window costs training
little (see benchmarks/studio.py).

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
from pathlib import Path

import numpy as np
from imgui_bundle import (
    imgui,  # before glfw: imgui-bundle points pyglfw at its own libglfw (DESIGN.md)
    implot,
)

# isort: split
import glfw

from renderer.render_modes import RenderMode

from . import panels
from .export_job import ExportJob, ExportSettings
from .trainer_thread import Controls, TrainerThread

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


def _to_rgb8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        image = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(image[..., :3])


class StudioApp:
    """Everything one frame of the studio needs; ``script`` callbacks get this object."""

    def __init__(self, window, ctx, trainer: TrainerThread) -> None:
        from renderer.orbit_camera import OrbitCamera
        from renderer.splat_renderer import SplatRenderer

        self.window = window
        self.ctx = ctx
        self.trainer = trainer
        self.controls: Controls = trainer.controls
        self.scene = trainer.session.scene
        self.renderer = SplatRenderer(ctx, target_dtype="f4")
        self.orbit = OrbitCamera()
        self.orbit.snap_to(self.scene.frames[0].camera)
        self._framed = False
        self.mode = RenderMode.RGB
        self.show_gui = True
        self.show_ground_truth = False
        self.gt_view: int | None = None  # evaluation view shown as ground truth (None: the training frame)
        self.playing = False
        self._play_clock = time.perf_counter()
        self.frame_count = 0
        self.fps = 0.0
        self.last_input = time.perf_counter()
        self.should_close = False
        self._screenshots: list[Path] = []
        self.saved_screenshots: list[str] = []
        self._fbo = None
        self._fbo_size = None
        self._draw_key = None
        self._gt_tex = None
        self._gt_key = None
        self.last_drawn_snapshot = None  # (version, space, frame_index, step) of what is on screen
        self.rects: dict[str, list[float]] = {}
        self._fb_size, self._fb_size_frame = (0, 0), -1
        self.cache: dict = {}  # panels' per-frame caches (plot arrays, curves)
        # pose source: the video's frames or a novel sequence (played in the live view)
        self.pose_source = "video"
        self._novel: dict[str, int] = {}
        # Stage II settings as the panel shows them (copied into Controls on change)
        self.stage2_settings = panels._stage2_defaults()
        self.controls.update(stage2=dict(self.stage2_settings))
        # export
        self.export_settings = ExportSettings()
        self.export_job: ExportJob | None = None
        self.export_message: str | None = None
        self.saved_on_close: str | None = None
        self._last_changes = None

    # ----- the session (Stage I, then possibly Stage II: always read through the trainer) -------
    @property
    def session(self):
        return self.trainer.session

    # ----- API for scripts and panels ----------------------------------------------------------
    @property
    def frame_index(self) -> int:
        return self.controls.get().frame_index

    def set_frame(self, i: int) -> None:
        n = len(self.scene.frames)
        self.controls.update(frame_index=int(i) % n)

    @property
    def num_pose_frames(self) -> int:
        if self.pose_source == "video":
            return len(self.scene.frames)
        return self.trainer.novel_length

    @property
    def pose_frame(self) -> int:
        c = self.controls.get()
        return c.novel_index if c.novel else c.frame_index

    def set_pose_frame(self, i: int) -> None:
        if self.pose_source == "video":
            self.set_frame(i)
        else:
            self.controls.update(novel_index=int(i) % max(1, self.num_pose_frames))

    def set_pose_source(self, source: str) -> None:
        if source not in panels.POSE_SOURCES:
            raise ValueError(f"unknown pose source {source!r}; choose one of {panels.POSE_SOURCES}")
        self.pose_source = source
        self.controls.update(novel="" if source == "video" else source, novel_index=0)
        if source != "video":
            self.controls.update(space="observation")

    def set_mode(self, mode) -> None:
        self.mode = RenderMode.parse(mode)

    def set_space(self, space: str) -> None:
        self.controls.update(space=space)
        self._framed = False  # re-centre the orbit pivot on the next snapshot

    def push_stage2_settings(self, **changes) -> None:
        """Hand the Stage II settings to the trainer (applied between steps)."""
        self.stage2_settings.update(changes)
        v = self.controls.get().stage2_version + 1
        self.controls.update(stage2=dict(self.stage2_settings), stage2_version=v)

    def request_screenshot(self, path) -> None:
        self._screenshots.append(Path(path))

    def screenshot_path(self) -> str:
        return str(Path("exports") / f"studio_{time.strftime('%Y%m%d_%H%M%S')}_{self.frame_count:05d}.png")

    def close(self) -> None:
        self.should_close = True

    def snap_to_training_camera(self) -> None:
        self.gt_view = None
        self.orbit.snap_to(self.scene.frames[self.frame_index].camera, pivot=self._pivot())

    def snap_to_eval_view(self, k: int) -> None:
        v = self.scene.eval_views[k]
        self.set_pose_source("video")
        self.controls.update(space="observation", frame_index=v.frame_index)
        self.gt_view = k
        self.orbit.snap_to(v.camera, pivot=self._pivot())

    def frame_avatar(self) -> None:
        snap = self.session.snapshots.latest()
        if len(snap):
            self.orbit.look_at_bounds(snap.means)

    def _pivot(self):
        snap = self.session.snapshots.latest()
        return snap.means.mean(0) if len(snap) else None

    def mark(self, name: str) -> None:
        """Record the last widget's screen rectangle [x0, y0, x1, y1] (for GUI tests)."""
        a, b = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        self.rects[name] = [round(a.x, 1), round(a.y, 1), round(b.x, 1), round(b.y, 1)]

    # ----- export --------------------------------------------------------------------------
    def start_export(self) -> ExportJob | None:
        """Start exporting ``export_settings`` (mode: the live view's). An unwritable path or a
        bad setting is refused at once with ``export_message``; training goes on either way."""
        from app.export import frozen_copy

        if self.export_job is not None and not self.export_job.done:
            self.export_message = "an export is already running"
            return None
        e = self.export_settings
        e.mode = self.mode.value
        e.frame_index = self.frame_index
        try:
            e.validate()
        except (OSError, ValueError) as exc:
            self.export_message = f"cannot export: {exc}"
            print(f"wonderhuman-studio: {self.export_message}", file=sys.stderr)
            return None
        self.export_message = None
        background = tuple(float(c) for c in self.session.config.background)
        self.export_job = ExportJob(e.__class__(**vars(e)), self.trainer.call_between_steps(frozen_copy),
                                    background=background)
        return self.export_job

    def pump_export(self) -> None:
        job = self.export_job
        if job is None:
            return
        job.pump(self.ctx)
        if job.done and job.error and self.export_message is None:
            self.export_message = f"export failed: {job.error}"
            print(f"wonderhuman-studio: {self.export_message}", file=sys.stderr)

    def change_key(self) -> tuple:
        """What an idle window would show differently: new training values, snapshot, messages."""
        t = self.trainer
        return (len(t._history), self.session.snapshots.latest().version, id(self.session), t.error,
                t.stage2_message, t.last_saved, self.controls.get().paused)

    @property
    def exporting(self) -> bool:
        return self.export_job is not None and not self.export_job.done

    # ----- per frame -----------------------------------------------------------------------------
    def handle_input(self) -> None:
        io = imgui.get_io()
        d = io.mouse_delta
        if d.x or d.y or io.mouse_wheel or imgui.is_any_mouse_down() or imgui.is_any_item_active():
            self.last_input = time.perf_counter()
        if io.want_capture_mouse:
            return
        fh = max(1, self.framebuffer_size()[1])
        if imgui.is_mouse_dragging(imgui.MouseButton_.left) and (d.x or d.y):
            self.orbit.drag(d.x, d.y, "left", fh)
        elif (imgui.is_mouse_dragging(imgui.MouseButton_.right) or imgui.is_mouse_dragging(
                imgui.MouseButton_.middle)) and (d.x or d.y):
            self.orbit.drag(d.x, d.y, "right", fh)
        if io.mouse_wheel:
            self.orbit.scroll(io.mouse_wheel)

    def advance_playback(self) -> None:
        now = time.perf_counter()
        if not self.playing:
            self._play_clock = now
            return
        period = 1.0 / max(1e-3, float(self.scene.fps))
        if now - self._play_clock >= period:
            self._play_clock = now
            self.set_pose_frame(self.pose_frame + 1)

    def _ground_truth(self) -> np.ndarray | None:
        if self.gt_view is not None and self.gt_view < len(self.scene.eval_views):
            return self.scene.eval_views[self.gt_view].image
        if self.pose_source != "video" or self.controls.get().space != "observation":
            return None
        return self.scene.frames[self.frame_index].image

    def _gt_texture(self):
        image = self._ground_truth()
        if image is None:
            return None
        key = (id(image), image.shape)
        if key != self._gt_key:
            rgb = _to_rgb8(image)
            h, w = rgb.shape[:2]
            if self._gt_tex is None or self._gt_tex.size != (w, h):
                if self._gt_tex is not None:
                    self._gt_tex.release()
                self._gt_tex = self.ctx.texture((w, h), 3)
            self._gt_tex.write(rgb.tobytes())
            self._gt_key = key
        return self._gt_tex

    def framebuffer_size(self) -> tuple[int, int]:
        """The window's framebuffer size, asked of glfw once per frame (an X round trip)."""
        if self._fb_size_frame != self.frame_count:
            self._fb_size = tuple(glfw.get_framebuffer_size(self.window))
            self._fb_size_frame = self.frame_count
        return self._fb_size

    def view_size(self) -> tuple[int, int, int, int]:
        """(window width, height, splat view width, height): the left half with ground truth."""
        fw, fh = self.framebuffer_size()
        side = self.show_ground_truth and self._ground_truth() is not None
        return fw, fh, (max(1, fw // 2) if side else fw), fh

    def draw_ground_truth(self) -> None:
        """The ground-truth image in the right half (imgui background draw list), aspect kept."""
        if not self.show_ground_truth:
            return
        tex = self._gt_texture()
        if tex is None:
            return
        fw, fh, vw, _ = self.view_size()
        w, h = tex.size
        s = min((fw - vw) / w, fh / h)
        x0 = vw + 0.5 * ((fw - vw) - s * w)
        y0 = 0.5 * (fh - s * h)
        dl = imgui.get_background_draw_list()
        dl.add_image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(x0, y0), imgui.ImVec2(x0 + s * w, y0 + s * h))
        dl.add_text(imgui.ImVec2(vw + 8, fh - 22), 0xFFFFFFFF, "ground truth")

    def draw_scene(self) -> None:
        """Splats into the cached offscreen framebuffer when anything changed, then blit to the window."""
        fw, fh, vw, vh = self.view_size()
        if fw <= 0 or fh <= 0:
            return
        snap = self.session.snapshots.latest()
        if not self._framed and len(snap):
            self.orbit.snap_to(self.scene.frames[0].camera, pivot=snap.means.mean(0)) if snap.space == "observation" \
                else self.orbit.look_at_bounds(snap.means)
            self._framed = True
        if self._fbo_size != (vw, vh):
            if self._fbo is not None:
                self._fbo.release()
            self._fbo = self.ctx.simple_framebuffer((vw, vh), components=4)
            self._fbo_size = (vw, vh)
            self._draw_key = None
        cam = self.orbit.to_camera(vw, vh)
        background = tuple(float(c) for c in self.session.config.background) if self.mode is RenderMode.RGB \
            else (0.12, 0.12, 0.14)
        key = (snap.version, id(snap), self.mode, vw, vh, cam.K.tobytes(), cam.R.tobytes(), cam.t.tobytes(), background)
        if key != self._draw_key:
            self.renderer.set_snapshot(snap)
            self.renderer.render(cam, mode=self.mode, background=background, target=self._fbo)
            self._draw_key = key
            self.last_drawn_snapshot = (snap.version, snap.space, snap.frame_index, snap.step)
        self.ctx.screen.use()
        if vw != fw:
            self.ctx.clear(0.08, 0.08, 0.09)
        self.ctx.copy_framebuffer(self.ctx.screen, self._fbo)

    def compose(self, draw_data) -> np.ndarray:
        """This frame as the window shows it (splats + panels), drawn again into an offscreen
        framebuffer and read back (H, W, 3) uint8, top row first. Reading the window's own
        framebuffer is not reliable: under Xvfb it returned a frame from two swaps earlier."""
        return compose_frame(self.ctx, self.framebuffer_size(), draw_data, self._fbo)

    def save_screenshot(self, path, image: np.ndarray) -> str:
        from reconstruct.atomic import atomic_output

        path = Path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_output(path) as tmp:
                from PIL import Image

                Image.fromarray(image).save(tmp, format="PNG")
        except OSError as exc:
            self.export_message = f"screenshot not written: {exc}"
            print(f"wonderhuman-studio: {self.export_message}", file=sys.stderr)
            return ""
        self.saved_screenshots.append(str(path))
        return str(path)

    def write_rects(self, path) -> None:
        data = {"window": list(self.framebuffer_size()), "rects": self.rects}
        tmp = Path(str(path) + ".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(path)

    def release(self) -> None:
        if self.export_job is not None:
            self.export_job.cancel()
            self.export_job.join(10)
            self.export_job.release()
        if self._fbo is not None:
            self._fbo.release()
        if self._gt_tex is not None:
            self._gt_tex.release()
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


_last_input = [0.0]  # perf_counter of the last input event seen by glfw


def _watch_input(win) -> None:
    """glfw input callbacks that only note the time, so an idle loop that skips frames still
    wakes up to full speed on the first input event (imgui's backend chains to them)."""
    def note(*_args) -> None:
        _last_input[0] = time.perf_counter()

    glfw.set_cursor_pos_callback(win, note)
    glfw.set_mouse_button_callback(win, note)
    glfw.set_scroll_callback(win, note)
    glfw.set_key_callback(win, note)
    glfw.set_char_callback(win, note)
    glfw.set_window_size_callback(win, note)


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


def _error_loop(win, ctx, message: str, *, max_frames, screenshot, max_fps: float) -> None:
    """The window shows ``message`` until closed (or ``max_frames``)."""
    frames = 0
    period = 1.0 / max(1.0, max_fps)
    while not glfw.window_should_close(win):
        glfw.wait_events_timeout(period)
        imgui.backends.opengl3_new_frame()
        imgui.backends.glfw_new_frame()
        imgui.new_frame()
        quit_ = panels.draw_error_window(message)
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


def run_studio(scene_spec: str, run_dir=None, *, config=None, size=(1280, 800), max_frames: int | None = None,
               script: Callable[[StudioApp], None] | None = None, screenshot=None, publish_every: int = 5,
               progress: bool = True, max_fps: float = 30.0, idle_fps: float = 5.0, active_s: float = 1.5,
               idle_refresh_s: float = 1.0, gui_nice: int | None = 10, rects_path=None) -> int:
    """Open the studio on ``scene_spec`` (training a new avatar, or resuming ``run_dir``'s checkpoint)
    and run until the window closes, ``max_frames`` frames were drawn, or ``script`` calls
    ``app.close()``; closing saves a checkpoint first when there is a run folder. ``screenshot``:
    PNG of the last frame. Returns 0, or 2 when the scene could not be opened (the error is shown
    in the window and on stderr). Raises NoDisplayError without a display."""
    import moderngl

    win = open_window(*size)  # the window's GLX context first, before anything could make an EGL one
    imgui_ready = False
    trainer = app = None
    try:
        ctx = moderngl.create_context()
        imgui.create_context()
        implot.create_context()
        io = imgui.get_io()
        io.set_ini_filename("")
        imgui.style_colors_dark()
        _load_font(io)
        _watch_input(win)  # before imgui's backend, which chains these callbacks
        imgui.backends.glfw_init_for_opengl(ctypes.cast(win, ctypes.c_void_p).value, True)
        imgui.backends.opengl3_init("#version 330")
        imgui_ready = True

        from app.run_setup import open_session

        try:
            session = open_session(scene_spec, run_dir, config, progress=progress)
        except Exception as exc:  # noqa: BLE001 -- any failure to open is shown, not a crash
            message = f"{scene_spec}: {type(exc).__name__}: {exc}"
            print(f"wonderhuman-studio: could not open the scene {message}", file=sys.stderr)
            if not isinstance(exc, (ValueError, OSError, RuntimeError, KeyError)):
                traceback.print_exc()
            _error_loop(win, ctx, message, max_frames=max_frames, screenshot=screenshot, max_fps=max_fps)
            return SCENE_ERROR_RC
        trainer = TrainerThread(session, publish_every=publish_every)
        app = StudioApp(win, ctx, trainer)
        trainer.start()
        if gui_nice:
            _lower_this_thread(gui_nice)  # after the trainer thread started: it keeps its priority
        next_frame = time.perf_counter()
        last_frame = next_frame
        while not glfw.window_should_close(win) and not app.should_close:
            app.last_input = max(app.last_input, _last_input[0])
            active = time.perf_counter() - app.last_input < active_s or app.playing or app.exporting
            fps_cap = max_fps if active else idle_fps
            next_frame += 1.0 / fps_cap if fps_cap else 0.0
            wait = next_frame - time.perf_counter()
            if wait > 0:
                glfw.wait_events_timeout(wait)  # sleeps (freeing the GIL); returns at once on input
            else:
                glfw.poll_events()
            now = time.perf_counter()
            next_frame = max(next_frame, now) if now - next_frame < 1.0 / max(fps_cap, 1) else now
            if not active and script is None:
                # idle: a frame only when the trainer has something new (or once a second)
                changes = app.change_key()
                if changes == app._last_changes and now - last_frame < idle_refresh_s:
                    continue
                app._last_changes = changes
            dt = max(now - last_frame, 1e-6)
            last_frame = now
            app.fps = 1.0 / dt if app.fps == 0 else 0.9 * app.fps + 0.1 / dt
            imgui.backends.opengl3_new_frame()
            imgui.backends.glfw_new_frame()
            imgui.new_frame()
            if script is not None:
                script(app)
            app.handle_input()
            app.advance_playback()
            if imgui.is_key_pressed(imgui.Key.h) and not imgui.get_io().want_text_input:
                app.show_gui = not app.show_gui
            if app.show_gui:
                panels.draw_panels(app)
            app.draw_ground_truth()
            imgui.render()
            draw_data = imgui.get_draw_data()
            app.pump_export()
            app.draw_scene()
            last = max_frames is not None and app.frame_count + 1 >= max_frames
            final = screenshot is not None and (last or app.should_close or glfw.window_should_close(win))
            if (app._screenshots or final) and app._fbo is not None:
                image = app.compose(draw_data)
                for path in app._screenshots + ([Path(screenshot)] if final else []):
                    app.save_screenshot(path, image)
            app._screenshots.clear()
            if rects_path is not None and app.frame_count % 5 == 0:
                app.write_rects(rects_path)
            app.ctx.screen.use()
            imgui.backends.opengl3_render_draw_data(draw_data)
            app.frame_count += 1
            glfw.swap_buffers(win)
            if last:
                break
        return 0
    finally:
        if trainer is not None:
            running = trainer.running and not trainer.session.done
            trainer.stop(save=True)  # a checkpoint first when there is a run folder
            if trainer.last_saved and app is not None:
                app.saved_on_close = trainer.last_saved
                print(f"wonderhuman-studio: {'training stopped; ' if running else ''}saved {trainer.last_saved}",
                      file=sys.stderr)
        if app is not None:
            app.release()
        if imgui_ready:
            imgui.backends.opengl3_shutdown()
            imgui.backends.glfw_shutdown()
            implot.destroy_context()
            imgui.destroy_context()
        glfw.destroy_window(win)
        glfw.terminate()
