"""The studio window: glfw (OpenGL 3.3 core) + imgui-bundle's native glfw/opengl3 backends +
moderngl on the same context. The SplatRenderer draws the trainer's latest snapshot into an
offscreen framebuffer (only when the snapshot, camera, mode or size changed) that is blitted to
the window every frame; the imgui panels are drawn on top.

``run_studio(..., script=f)`` calls ``f(app)`` every frame so that tests can drive the GUI state
without real input (see tests/test_studio.py)."""

from __future__ import annotations

import ctypes
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
from imgui_bundle import (
    imgui,  # before glfw: imgui-bundle points pyglfw at its own libglfw (DESIGN.md)
)

# isort: split
import glfw

from renderer.render_modes import RenderMode

from . import panels
from .trainer_thread import Controls, TrainerThread

NO_DISPLAY_MESSAGE = ("wonderhuman-studio: no display to open the studio window on (DISPLAY/WAYLAND_DISPLAY unset "
                      "or the window could not open); headless: `wonderhuman-studio demo`, `train` or `export`")


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
    glfw.swap_interval(1)
    return win


class StudioApp:
    """Everything one frame of the studio needs; ``script`` callbacks get this object."""

    def __init__(self, window, ctx, session, trainer: TrainerThread) -> None:
        from renderer.orbit_camera import OrbitCamera
        from renderer.splat_renderer import SplatRenderer

        self.window = window
        self.ctx = ctx
        self.session = session
        self.trainer = trainer
        self.controls: Controls = trainer.controls
        self.scene = session.scene
        self.renderer = SplatRenderer(ctx, target_dtype="f4")
        self.orbit = OrbitCamera()
        self.orbit.snap_to(self.scene.frames[0].camera)
        self._framed = False
        self.mode = RenderMode.RGB
        self.show_gui = True
        self.playing = False
        self._play_clock = time.perf_counter()
        self.frame_count = 0
        self.should_close = False
        self._screenshots: list[Path] = []
        self.saved_screenshots: list[str] = []
        self._fbo = None
        self._fbo_size = None
        self._draw_key = None
        self.last_drawn_snapshot = None  # (version, space, frame_index, step) of what is on screen

    # ----- API for scripts and panels ----------------------------------------------------------
    @property
    def frame_index(self) -> int:
        return self.controls.get().frame_index

    def set_frame(self, i: int) -> None:
        n = len(self.scene.frames)
        self.controls.update(frame_index=int(i) % n)

    def set_mode(self, mode) -> None:
        self.mode = RenderMode.parse(mode)

    def set_space(self, space: str) -> None:
        self.controls.update(space=space)
        self._framed = False  # re-centre the orbit pivot on the next snapshot

    def request_screenshot(self, path) -> None:
        self._screenshots.append(Path(path))

    def close(self) -> None:
        self.should_close = True

    def snap_to_training_camera(self) -> None:
        self.orbit.snap_to(self.scene.frames[self.frame_index].camera, pivot=self._pivot())

    def snap_to_eval_view(self, k: int) -> None:
        v = self.scene.eval_views[k]
        self.controls.update(space="observation", frame_index=v.frame_index)
        self.orbit.snap_to(v.camera, pivot=self._pivot())

    def frame_avatar(self) -> None:
        snap = self.session.snapshots.latest()
        if len(snap):
            self.orbit.look_at_bounds(snap.means)

    def _pivot(self):
        snap = self.session.snapshots.latest()
        return snap.means.mean(0) if len(snap) else None

    # ----- per frame -----------------------------------------------------------------------------
    def handle_input(self) -> None:
        io = imgui.get_io()
        if io.want_capture_mouse:
            return
        fh = max(1, glfw.get_framebuffer_size(self.window)[1])
        d = io.mouse_delta
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
            self.set_frame(self.frame_index + 1)

    def draw_scene(self) -> None:
        """Splats into the cached offscreen framebuffer when anything changed, then blit to the window."""
        fw, fh = glfw.get_framebuffer_size(self.window)
        if fw <= 0 or fh <= 0:
            return
        snap = self.session.snapshots.latest()
        if not self._framed and len(snap):
            self.orbit.snap_to(self.scene.frames[0].camera, pivot=snap.means.mean(0)) if snap.space == "observation" \
                else self.orbit.look_at_bounds(snap.means)
            self._framed = True
        if self._fbo_size != (fw, fh):
            if self._fbo is not None:
                self._fbo.release()
            self._fbo = self.ctx.simple_framebuffer((fw, fh), components=4)
            self._fbo_size = (fw, fh)
            self._draw_key = None
        cam = self.orbit.to_camera(fw, fh)
        background = tuple(float(c) for c in self.session.config.background) if self.mode is RenderMode.RGB \
            else (0.12, 0.12, 0.14)
        key = (snap.version, id(snap), self.mode, fw, fh, cam.K.tobytes(), cam.R.tobytes(), cam.t.tobytes(), background)
        if key != self._draw_key:
            self.renderer.set_snapshot(snap)
            self.renderer.render(cam, mode=self.mode, background=background, target=self._fbo)
            self._draw_key = key
            self.last_drawn_snapshot = (snap.version, snap.space, snap.frame_index, snap.step)
        self.ctx.copy_framebuffer(self.ctx.screen, self._fbo)

    def compose(self, draw_data) -> np.ndarray:
        """This frame as the window shows it (splats + panels), drawn again into an offscreen
        framebuffer and read back (H, W, 3) uint8, top row first. Reading the window's own
        framebuffer is not reliable: under Xvfb it returned a frame from two swaps earlier."""
        fw, fh = self._fbo_size
        shot = self.ctx.simple_framebuffer((fw, fh), components=4)
        try:
            self.ctx.copy_framebuffer(shot, self._fbo)
            shot.use()
            imgui.backends.opengl3_render_draw_data(draw_data)
            data = shot.read(components=3, alignment=1)
        finally:
            self.ctx.screen.use()
            shot.release()
        return np.frombuffer(data, np.uint8).reshape(fh, fw, 3)[::-1].copy()

    def save_screenshot(self, path, image: np.ndarray) -> str:
        from PIL import Image

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(path)
        self.saved_screenshots.append(str(path))
        return str(path)

    def release(self) -> None:
        if self._fbo is not None:
            self._fbo.release()
        self.renderer.release()


def run_studio(scene_spec: str, run_dir=None, *, config=None, size=(1280, 800), max_frames: int | None = None,
               script: Callable[[StudioApp], None] | None = None, screenshot=None, publish_every: int = 5,
               progress: bool = True, max_fps: float = 30.0) -> int:
    """Open the studio on ``scene_spec`` (training a new avatar, or resuming ``run_dir``'s checkpoint)
    and run until the window closes, ``max_frames`` frames were drawn, or ``script`` calls
    ``app.close()``. ``screenshot``: PNG of the last frame. ``max_fps`` caps the GUI's frame rate:
    the GUI and the training thread share the interpreter, and an uncapped GUI (70 frames/s on
    llvmpipe) halved the training speed. Raises NoDisplayError without a display."""
    import moderngl

    win = open_window(*size)  # the window's GLX context first, before anything could make an EGL one
    imgui_ready = False
    trainer = app = None
    try:
        ctx = moderngl.create_context()
        imgui.create_context()
        io = imgui.get_io()
        io.set_ini_filename("")
        imgui.style_colors_dark()
        imgui.backends.glfw_init_for_opengl(ctypes.cast(win, ctypes.c_void_p).value, True)
        imgui.backends.opengl3_init("#version 330")
        imgui_ready = True

        from app.run_setup import open_session

        session = open_session(scene_spec, run_dir, config, progress=progress)
        trainer = TrainerThread(session, publish_every=publish_every)
        app = StudioApp(win, ctx, session, trainer)
        trainer.start()
        frame_time = 1.0 / max_fps if max_fps else 0.0
        next_frame = time.perf_counter()
        while not glfw.window_should_close(win) and not app.should_close:
            next_frame += frame_time
            glfw.wait_events_timeout(max(0.0, next_frame - time.perf_counter()))  # sleeps, freeing the GIL
            next_frame = max(next_frame, time.perf_counter())
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
            imgui.render()
            draw_data = imgui.get_draw_data()
            app.draw_scene()
            last = max_frames is not None and app.frame_count + 1 >= max_frames
            final = screenshot is not None and (last or app.should_close or glfw.window_should_close(win))
            if (app._screenshots or final) and app._fbo is not None:
                image = app.compose(draw_data)
                for path in app._screenshots + ([Path(screenshot)] if final else []):
                    app.save_screenshot(path, image)
            app._screenshots.clear()
            app.ctx.screen.use()
            imgui.backends.opengl3_render_draw_data(draw_data)
            app.frame_count += 1
            glfw.swap_buffers(win)
            if last:
                break
        return 0
    finally:
        if trainer is not None:
            trainer.stop(save=True)
        if app is not None:
            app.release()
        if imgui_ready:
            imgui.backends.opengl3_shutdown()
            imgui.backends.glfw_shutdown()
            imgui.destroy_context()
        glfw.destroy_window(win)
        glfw.terminate()
