"""Where the panels go: the left column (control) and the right column (view, export), each panel
at its initial height. ``panels.PANELS`` lists the studio's; ``STUDIO_PANELS`` adds the Beside panel
(a .ply beside the live avatar, bottom right); ``HEIGHTS`` overrides initial heights (the Pose panel
holds the motion-file field). The Edit panel, while open (``ViewState.edit_panel``: its switch is in
the tool bar at the top of the viewport), takes the left column's place, full height."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from imgui_bundle import imgui

from . import panels
from .panels import beside, edit, footage

HEIGHTS = {"Pose": 215, "Export": 255}
GAP = 8.0
EDIT_WIDTH = 380.0
MARGIN = 10.0

PanelSpec = tuple[str, Callable, int, int]  # title, draw(ui), column, initial height
STUDIO_PANELS: tuple[PanelSpec, ...] = (*panels.PANELS, (".ply beside the avatar", beside.draw, 1, 105),
                                        ("Your video or photo", footage.draw, 0, 330))
COLLAPSED = {"Your video or photo"}  # title bars only until opened (the columns are full at 1280 x 800)


def draw_panels(ui, specs: Iterable[PanelSpec] | None = None, heights: dict | None = None) -> None:
    """Draw ``specs`` (default ``panels.PANELS``) as imgui windows, columns stacked from the top."""
    specs = panels.PANELS if specs is None else specs
    heights = HEIGHTS if heights is None else heights
    width = panels.PANEL_WIDTH
    fw = imgui.get_io().display_size.x
    ys = [MARGIN, MARGIN]
    view = getattr(ui, "view", None)
    editing = bool(getattr(view, "edit_panel", False)) and getattr(ui, "edits", None) is not None
    for title, body, col, height in specs:
        if title == edit.TITLE and not editing or editing and col == 0 and title != edit.TITLE:
            continue
        if title == edit.TITLE:
            height = imgui.get_io().display_size.y - 2 * MARGIN
        height = heights.get(title, height)
        w = EDIT_WIDTH if title == edit.TITLE else width
        x = MARGIN if col == 0 else max(MARGIN + width + GAP, fw - width - MARGIN)
        imgui.set_next_window_pos(imgui.ImVec2(x, ys[col]), imgui.Cond_.first_use_ever)
        imgui.set_next_window_size(imgui.ImVec2(w, height), imgui.Cond_.first_use_ever)
        if title in COLLAPSED:
            imgui.set_next_window_collapsed(True, imgui.Cond_.first_use_ever)
            height = 20
        ys[col] += height + GAP
        if imgui.begin(title)[0]:
            imgui.push_item_width(w * 0.52)
            body(ui)
            imgui.pop_item_width()
        imgui.end()
    if getattr(ui, "edits", None) is not None:
        edit.draw_toolbar(ui)
