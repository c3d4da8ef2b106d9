"""Beside panel: Gaussians from a file (an earlier export, another program's .ply, .splat, .spz or .sog)
drawn beside the live avatar, with the same render mode and camera; errors shown here, the live
view untouched."""

from __future__ import annotations

from imgui_bundle import imgui

from .common import error_text, wrapped_hint
from .context import PanelContext


def draw(ui: PanelContext) -> None:
    view = ui.view
    f = view.beside
    ch, path = imgui.input_text("path##beside", f.path)
    ui.mark("beside_path")
    if ch:
        f.path = path
    imgui.begin_disabled(f.loading)
    if imgui.button("Open##beside"):
        ui.actions.open_beside_ply()
    ui.mark("open_beside")
    imgui.end_disabled()
    if f.loaded is not None:
        imgui.same_line()
        ch, v = imgui.checkbox("show", view.show_beside)
        if ch:
            view.show_beside = v
        imgui.same_line()
        if imgui.small_button("remove"):
            ui.actions.clear_beside_ply()
        wrapped_hint(f"{f.loaded.name}: {f.loaded.summary()}")
    elif f.loading:
        imgui.same_line()
        imgui.text_disabled("reading...")
    if f.message:
        error_text(f.message)
