"""The studio's panels, one file each (nerfstudio-style control / render / export split): Training
and Stage II (control) in the left column, Render, Pose and Export on the right; Edit (selection
tools, region actions, undo and the edit list) takes the left column while it is open. Each panel is a
``draw(ui: PanelContext)``: it reads the view state and the trainer's status and calls actions."""

from __future__ import annotations

from imgui_bundle import imgui

from . import edit, export, pose, render, stage2, training
from .common import error_text
from .context import PanelContext, StudioActions

PANEL_WIDTH = 320
# title, draw, column, initial height
PANELS = (("Training", training.draw, 0, 345), ("Stage II", stage2.draw, 0, 427), ("Render", render.draw, 1, 200),
          ("Pose", pose.draw, 1, 110), ("Export", export.draw, 1, 300),
          (edit.TITLE, edit.draw, 0, 780))  # shown instead of the left column's panels (layout.py)

__all__ = ["PANELS", "PanelContext", "StudioActions", "draw_panels", "draw_error_window"]


def draw_panels(ui: PanelContext) -> None:
    fw = imgui.get_io().display_size.x
    ys = [10.0, 10.0]
    for title, body, col, height in PANELS:
        if title == edit.TITLE:
            continue
        x = 10.0 if col == 0 else max(10.0 + PANEL_WIDTH + 8, fw - PANEL_WIDTH - 10)
        imgui.set_next_window_pos(imgui.ImVec2(x, ys[col]), imgui.Cond_.first_use_ever)
        imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, height), imgui.Cond_.first_use_ever)
        ys[col] += height + 8
        if imgui.begin(title)[0]:
            imgui.push_item_width(PANEL_WIDTH * 0.52)
            body(ui)
            imgui.pop_item_width()
        imgui.end()


def draw_error_window(message: str, hint: str = "Start again with --scene SCENE (a scene folder or synthetic:seed=S).",
                      title: str = "Could not open the scene") -> bool:
    """An error, centred. Returns True when the user asks to quit."""
    io = imgui.get_io()
    w = min(640.0, io.display_size.x - 20)
    imgui.set_next_window_pos(imgui.ImVec2(0.5 * (io.display_size.x - w), 40), imgui.Cond_.always)
    imgui.set_next_window_size(imgui.ImVec2(w, 0), imgui.Cond_.always)
    quit_ = False
    if imgui.begin(title, None, imgui.WindowFlags_.no_collapse)[0]:
        error_text(message)
        imgui.spacing()
        imgui.text_disabled(hint)
        quit_ = imgui.button("Quit")
    imgui.end()
    return quit_
