"""The .ply viewer's panels (``wonderhuman-studio --ply FILE``: no trainer, so no Training, Stage II,
Pose or Export panels): File (open another .ply, what the file holds, errors) and View (render
mode, camera)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from imgui_bundle import imgui

from renderer.render_modes import RenderMode

from ..ply_source import FOREIGN_UPS, PlyFileState
from .common import error_text, wrapped_hint

MODES = list(RenderMode)
VIEWS = (("front", 0.0), ("left", 90.0), ("back", 180.0), ("right", -90.0))


class ViewerActions(Protocol):
    def open_ply(self, path: str | None = None) -> None: ...
    def set_mode(self, mode) -> None: ...
    def frame_avatar(self) -> None: ...
    def view_from(self, azimuth: float) -> None: ...
    def request_screenshot(self, path) -> None: ...
    def screenshot_path(self) -> str: ...


@dataclass
class ViewerContext:
    file: PlyFileState
    mode: RenderMode
    actions: ViewerActions
    fps: float = 0.0
    saved_screenshots: list = field(default_factory=list)
    mark: object = lambda name: None


def draw_file(ui: ViewerContext) -> None:
    f = ui.file
    loaded = f.loaded
    if loaded is not None:
        imgui.text(loaded.name)
        wrapped_hint(loaded.summary())
    else:
        imgui.text_disabled("no file shown")
    imgui.separator_text("open a .ply, .splat, .spz or .sog")
    ch, path = imgui.input_text("path##ply", f.path)
    ui.mark("ply_path")
    if ch:
        f.path = path
    keys = [k for k, _ in FOREIGN_UPS]
    ch, idx = imgui.combo("other files' up", keys.index(f.foreign_up), [label for _, label in FOREIGN_UPS])
    if ch:
        f.foreign_up = keys[idx]
    imgui.begin_disabled(f.loading)
    if imgui.button("Open##ply"):
        ui.actions.open_ply()
    ui.mark("open_ply")
    imgui.end_disabled()
    if f.loading:
        imgui.same_line()
        imgui.text_disabled("reading...")
    if f.message:
        error_text(f.message)


def draw_view(ui: ViewerContext) -> None:
    opened = imgui.begin_combo("mode", ui.mode.label)
    ui.mark("mode")
    if opened:
        for mm in MODES:
            if imgui.selectable(mm.label, mm is ui.mode)[0]:
                ui.actions.set_mode(mm)
        imgui.end_combo()
    for k, (name, az) in enumerate(VIEWS):
        if k:
            imgui.same_line()
        if imgui.small_button(name):
            ui.actions.view_from(az)
    if imgui.button("frame the Gaussians"):
        ui.actions.frame_avatar()
    if imgui.button("Screenshot (PNG)"):
        ui.actions.request_screenshot(ui.actions.screenshot_path())
    if ui.saved_screenshots:
        imgui.same_line()
        imgui.text_disabled(ui.saved_screenshots[-1][-32:])
    imgui.text_disabled(f"GUI {ui.fps:4.1f} fps")
    imgui.text_disabled("drag: orbit, right-drag: pan, wheel: zoom, H: hide")
    if ui.mode is RenderMode.VISIBILITY:
        wrapped_hint("a .ply carries no visibility flags: every Gaussian shows as unseen")


# title, draw, column, initial height (app.studio.layout.draw_panels)
VIEWER_PANELS = (("File", draw_file, 1, 230), ("View", draw_view, 1, 190))
