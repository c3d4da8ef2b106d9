"""The .ply viewer: ``wonderhuman-studio --ply FILE`` shows any 3DGS ``.ply`` (ours or another
program's) with the studio's render modes and orbit camera, and no training: there is no trainer,
so the panels that need one (Training, Stage II, Pose, Export) are not there; File (open another
.ply) and View (mode, camera, screenshot) are.

Same window set-up as the studio (``window.gui_window``); the file is read in a background thread
and the GL thread only polls it. A file that cannot be read at start is shown as the studio shows a
scene that cannot be opened (an error window, exit status 2); a later one that cannot be read is
shown in the File panel and the file on screen stays."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

import glfw
import numpy as np
from imgui_bundle import imgui

from renderer.render_modes import RenderMode

from .layout import draw_panels
from .orbit_input import apply_mouse
from .pacing import FramePacer
from .panels.viewer import VIEWER_PANELS, ViewerContext
from .drops import DropQueue, drop_kind, not_taken
from .ply_source import PlyFileState, read_ply_for_view
from .window import SCENE_ERROR_RC, _error_loop, _save_png, compose_frame, gui_window

BACKGROUND = (0.0, 0.0, 0.0)
OTHER_BACKGROUND = (0.12, 0.12, 0.14)


class ViewerApp:
    """One viewer window: the file shown, the render mode, the orbit camera and the panels' actions.
    ``run_viewer``'s ``script`` gets this object each frame."""

    def __init__(self, window, ctx, info, pacer: FramePacer | None = None) -> None:
        from renderer.orbit_camera import OrbitCamera
        from renderer.splat_renderer import SplatRenderer

        self.window = window
        self.drops = DropQueue()
        self.drops.install(glfw, window)
        self.ctx = ctx
        self.pacer = pacer or FramePacer()
        self.renderer = SplatRenderer(ctx, target_dtype="f4")
        self.orbit = OrbitCamera()
        self.file = PlyFileState(path=info.path, loaded=info)
        self.mode = RenderMode.RGB
        self.show_gui = True
        self.frame_count = 0
        self.should_close = False
        self.saved_screenshots: list[str] = []
        self._screenshots: list[Path] = []
        self._fbo = None
        self._fbo_size = None
        self._draw_key = None
        self._version = 0
        self.rects: dict[str, list[float]] = {}
        self._show(info)

    # ----- what scripts and tests read ----------------------------------------------------------
    @property
    def snapshot(self):
        return self.file.loaded.snapshot

    @property
    def fps(self) -> float:
        return self.pacer.fps

    # ----- actions --------------------------------------------------------------------------------
    def open_ply(self, path: str | None = None) -> bool:
        """Read ``path`` (default: the File panel's field) in the background; shown when read."""
        if self.file.loading:
            self.file.message = "a file is being read; wait for it"
            return False
        self.file.start(path)
        return True

    def handle_drops(self, paths=None) -> None:
        """Files dropped on the window: the last splat file dropped opens; others are a message."""
        for path in self.drops.take() if paths is None else paths:
            if drop_kind(path) == "splat":
                self.open_ply(path)
            else:
                self.file.message = not_taken(path) + " (the viewer opens splat files)"

    def poll_file(self) -> None:
        job = self.file.job
        if job is None or not job.done:
            return
        self.file.job = None
        if job.error is not None:
            self.file.message = f"could not open the .ply: {job.error}"
            print(f"wonderhuman-studio: {self.file.message}", file=sys.stderr)
            return
        self.file.loaded, self.file.message = job.result, None
        self._show(job.result)

    def _show(self, info) -> None:
        self._version += 1
        object.__setattr__(info.snapshot, "version", self._version)
        self.frame_avatar()

    def set_mode(self, mode) -> None:
        self.mode = RenderMode.parse(mode)

    def frame_avatar(self) -> None:
        means = self.snapshot.means
        self.orbit.look_at_bounds(means)
        extent = float(np.linalg.norm(np.ptp(means, axis=0))) if len(means) else 1.0
        self.orbit.far = max(100.0, self.orbit.distance + 4.0 * extent)
        self.orbit.near = max(1e-3, min(0.01, 0.01 * extent))

    def view_from(self, azimuth: float) -> None:
        self.orbit.orbit(float(azimuth) - self.orbit.azimuth, -self.orbit.elevation)

    def request_screenshot(self, path) -> None:
        self._screenshots.append(Path(path))

    def screenshot_path(self) -> str:
        return str(Path("exports") / f"viewer_{time.strftime('%Y%m%d_%H%M%S')}_{self.frame_count:05d}.png")

    def close(self) -> None:
        self.should_close = True

    def mark(self, name: str) -> None:
        a, b = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        self.rects[name] = [round(a.x, 1), round(a.y, 1), round(b.x, 1), round(b.y, 1)]

    def change_key(self) -> tuple:
        return (self._version, self.file.loading, self.file.message)

    # ----- per frame -----------------------------------------------------------------------------
    def handle_input(self) -> None:
        if apply_mouse(self.orbit, self.pacer, glfw.get_framebuffer_size(self.window)[1]):
            self.show_gui = not self.show_gui

    def draw_scene(self, size) -> None:
        fw, fh = size
        if fw <= 0 or fh <= 0:
            return
        if self._fbo_size != (fw, fh):
            if self._fbo is not None:
                self._fbo.release()
            self._fbo = self.ctx.simple_framebuffer((fw, fh), components=4)
            self._fbo_size = (fw, fh)
            self._draw_key = None
        cam = self.orbit.to_camera(fw, fh)
        background = BACKGROUND if self.mode is RenderMode.RGB else OTHER_BACKGROUND
        key = (self._version, self.mode, fw, fh, cam.K.tobytes(), cam.R.tobytes(), cam.t.tobytes())
        if key != self._draw_key:
            self.renderer.set_snapshot(self.snapshot)
            self.renderer.render(cam, mode=self.mode, background=background, target=self._fbo)
            self._draw_key = key
        self.ctx.screen.use()
        self.ctx.copy_framebuffer(self.ctx.screen, self._fbo)

    def context(self) -> ViewerContext:
        return ViewerContext(file=self.file, mode=self.mode, actions=self, fps=self.fps,
                             saved_screenshots=self.saved_screenshots, mark=self.mark)

    def frame(self, script=None, *, screenshot=None, last: bool = False) -> None:
        imgui.backends.opengl3_new_frame()
        imgui.backends.glfw_new_frame()
        imgui.new_frame()
        if script is not None:
            script(self)
        self.handle_drops()
        self.poll_file()
        self.handle_input()
        if self.show_gui:
            draw_panels(self.context(), VIEWER_PANELS, {})
        imgui.render()
        draw_data = imgui.get_draw_data()
        size = tuple(glfw.get_framebuffer_size(self.window))
        self.draw_scene(size)
        final = screenshot is not None and (last or self.should_close or glfw.window_should_close(self.window))
        if (self._screenshots or final) and self._fbo is not None:
            image = compose_frame(self.ctx, size, draw_data, self._fbo)
            for path in self._screenshots + ([Path(screenshot)] if final else []):
                try:
                    _save_png(path, image)
                    self.saved_screenshots.append(str(path))
                except OSError as exc:
                    self.file.message = f"screenshot not written: {exc}"
        self._screenshots.clear()
        self.ctx.screen.use()
        imgui.backends.opengl3_render_draw_data(draw_data)
        self.frame_count += 1
        glfw.swap_buffers(self.window)

    def release(self) -> None:
        if self._fbo is not None:
            self._fbo.release()
        self.renderer.release()


def run_viewer(path, *, size=(1280, 800), max_frames: int | None = None,
               script: Callable[[ViewerApp], None] | None = None, screenshot=None, max_fps: float = 30.0,
               idle_fps: float = 5.0, foreign_up: str = "y_down") -> int:
    """Show the 3DGS ``.ply`` at ``path`` until the window closes (or ``max_frames``, or ``script``
    calls ``app.close()``). Returns 0, or 2 when the file cannot be read (the error is shown in the
    window and on stderr, as the studio does for a scene). Raises NoDisplayError without a display."""
    pacer = FramePacer(max_fps=max_fps, idle_fps=idle_fps)
    with gui_window(size, pacer, title=f"WonderHuman Studio - {Path(str(path)).name}") as (win, ctx):
        try:
            info = read_ply_for_view(path, foreign_up)
        except (ValueError, OSError) as exc:
            message = str(exc)
            print(f"wonderhuman-studio: could not open the .ply {message}", file=sys.stderr)
            _error_loop(win, ctx, message, max_frames=max_frames, screenshot=screenshot, max_fps=max_fps,
                        title="Could not open the .ply",
                        hint="Start again with --ply FILE (a 3D Gaussian Splatting .ply: docs/ply.md).")
            return SCENE_ERROR_RC
        app = ViewerApp(win, ctx, info, pacer)
        try:
            while not glfw.window_should_close(win) and not app.should_close:
                if not pacer.wait(glfw.wait_events_timeout, glfw.poll_events, busy=app.file.loading,
                                  changes=app.change_key(), always=script is not None):
                    continue
                last = max_frames is not None and app.frame_count + 1 >= max_frames
                app.frame(script, screenshot=screenshot, last=last)
                if last:
                    break
            return 0
        finally:
            app.release()
