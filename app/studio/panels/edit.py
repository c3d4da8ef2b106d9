"""Edit panel (docs/editing.md, "In the studio window"): the selection tools (orbit / brush /
rectangle / lasso, brush radius, visible surface or through the body, combine mode), selection by
body part, grow / shrink / invert / clear; region actions (mark seen / unseen, lock, erase,
recolour, redo + guidance steps); undo / redo and the list of edits. Also the tool bar at the top of
the viewport. Everything goes through ``ui.edits`` (app.studio.edit_controller.EditController)."""

from __future__ import annotations

from imgui_bundle import imgui

from reconstruct.avatar.garment_layer import AVATAR_PART_NAMES
from reconstruct.edits import Erase, Lock, PaintSeen, PaintUnseen, Recolour, Redo
from reconstruct.edits.selection import GROUPS

from ..edit_tools import COMBINE_MODES, TOOL_LABELS, TOOLS
from .common import error_text, wrapped_hint
from .context import PanelContext

PART_CHOICES = (*GROUPS, *AVATAR_PART_NAMES)  # the body's parts and "garment" (a garment layer)
TITLE = "Edit"
BUSY_RGBA = (1.0, 0.85, 0.35, 1.0)  # "applying..." (not red: red is for errors)


def _tool_buttons(ui: PanelContext, prefix: str) -> None:
    ed = ui.edits
    for k, tool in enumerate(TOOLS):
        if k:
            imgui.same_line()
        active = ed.tools.tool == tool
        if active:  # the active tool in the style's pressed-button colour
            imgui.push_style_color(imgui.Col_.button, imgui.get_style_color_vec4(imgui.Col_.button_active))
        if imgui.button(f"{TOOL_LABELS[tool]}##{prefix}{tool}"):
            ed.set_tool(tool)
        if active:
            imgui.pop_style_color()
        ui.mark(f"{prefix}tool_{tool}")


def draw_toolbar(ui: PanelContext) -> None:
    """The tools and the Edit panel's switch, in a bar at the top centre of the viewport."""
    ed = ui.edits
    if ed is None:
        return
    io = imgui.get_io()
    flags = (imgui.WindowFlags_.no_title_bar | imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_move
             | imgui.WindowFlags_.no_saved_settings | imgui.WindowFlags_.no_focus_on_appearing)
    imgui.set_next_window_pos(imgui.ImVec2(0.5 * io.display_size.x, 10.0), imgui.Cond_.always, imgui.ImVec2(0.5, 0.0))
    imgui.set_next_window_bg_alpha(0.85)
    if imgui.begin("##edit_toolbar", None, flags)[0]:
        _tool_buttons(ui, "")
        imgui.same_line()
        ch, v = imgui.checkbox("Edit panel", ui.view.edit_panel)
        ui.mark("edit_panel_toggle")
        if ch:
            ui.view.edit_panel = v
        imgui.same_line()
        if ed.busy:
            imgui.text_colored(imgui.ImVec4(*BUSY_RGBA), "applying...")
        else:
            imgui.text_disabled(f"{ed.selected_count} selected")
    imgui.end()


def _selection(ui: PanelContext) -> None:
    ed, t = ui.edits, ui.edits.tools
    imgui.separator_text("select")
    _tool_buttons(ui, "p_")
    imgui.begin_disabled(t.tool != "brush")
    ch, v = imgui.slider_float("brush radius (px)", float(t.radius), 2.0, 120.0, "%.0f")
    ui.mark("brush_radius")
    if ch:
        t.radius = v
    imgui.end_disabled()
    ch, v = imgui.checkbox("through the body (else the visible surface)", t.through)
    ui.mark("through")
    if ch:
        t.through = v
    ch, idx = imgui.combo("combine", COMBINE_MODES.index(t.mode), list(COMBINE_MODES))
    ui.mark("combine")
    if ch:
        t.mode = COMBINE_MODES[idx]
    imgui.text_disabled("Shift+drag: add, Ctrl+drag: subtract")
    p = ed.panel
    ch, idx = imgui.combo("body part", PART_CHOICES.index(p.part) if p.part in PART_CHOICES else 0, list(PART_CHOICES))
    ui.mark("part")
    if ch:
        p.part = PART_CHOICES[idx]
    imgui.same_line()
    if imgui.button("Select##part"):
        ed.select_part()
    ui.mark("select_part")
    for k, (label, fn) in enumerate((("Grow", ed.grow), ("Shrink", ed.shrink), ("Invert", ed.invert),
                                     ("Clear", ed.clear))):
        if k:
            imgui.same_line()
        if imgui.button(label):
            fn()
        ui.mark(f"sel_{label.lower()}")
    s = ed.session
    n = ed.selected_count
    imgui.text(f"{n} of {s.num_gaussians} Gaussians selected")
    if n and s.selection_label:
        wrapped_hint(s.selection_label[-120:])


def _actions(ui: PanelContext) -> None:
    ed, p, st = ui.edits, ui.edits.panel, ui.status
    imgui.separator_text("region actions")
    imgui.begin_disabled(ed.busy or ed.selected_count == 0)
    for k, (label, name, op) in enumerate((("Mark seen", "seen", PaintSeen()), ("Mark unseen", "unseen", PaintUnseen()),
                                           ("Lock", "lock", Lock()), ("Erase", "erase", Erase()))):
        if k:
            imgui.same_line()
        if imgui.button(label):
            ed.apply(op)
        ui.mark(f"op_{name}")
    ch, v = imgui.slider_float("hue (deg)", float(p.hue), -180.0, 180.0, "%.0f")
    if ch:
        p.hue = v
    ch, v = imgui.slider_float("saturation x", float(p.saturation), 0.0, 2.0, "%.2f")
    if ch:
        p.saturation = v
    ch, v = imgui.slider_float("brightness x", float(p.value), 0.0, 2.0, "%.2f")
    if ch:
        p.value = v
    if imgui.button("Apply recolour"):
        ed.apply(Recolour(round(p.hue, 2), round(p.saturation, 3), round(p.value, 3)))
    ui.mark("op_recolour")
    imgui.same_line()
    if imgui.button("Redo region"):
        ed.apply(Redo())
    ui.mark("op_redo")
    imgui.end_disabled()
    ch, v = imgui.input_int("guidance steps", int(p.guidance_steps), 1, 10)
    if ch:
        p.guidance_steps = max(1, min(1000, v))
    imgui.begin_disabled(ed.busy or st.stage < 2)
    if imgui.button("Run guidance steps"):
        ed.run_guidance()
    ui.mark("run_guidance")
    imgui.end_disabled()
    if st.stage < 2:
        imgui.same_line()
        imgui.text_disabled("(Stage II)")


def _history(ui: PanelContext) -> None:
    ed, p = ui.edits, ui.edits.panel
    s = ed.session
    imgui.separator_text("undo")
    imgui.begin_disabled(ed.busy or not s.can_undo)
    if imgui.button("Undo (Ctrl+Z)"):
        ed.undo()
    ui.mark("undo")
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(ed.busy or not s.can_redo)
    if imgui.button("Redo (Ctrl+Shift+Z)"):
        ed.redo()
    ui.mark("redo")
    imgui.end_disabled()
    if ed.busy:
        imgui.text_colored(imgui.ImVec4(*BUSY_RGBA), f"applying: {p.pending_what}...")
    elif p.result:
        imgui.text_disabled(p.result[:90])
    if p.message:
        error_text(p.message)
    entries = ed.entries()
    imgui.separator_text(f"edits ({sum(a for _, a in entries)} applied, {sum(not a for _, a in entries)} undone)")
    if imgui.begin_child("##edit_list", imgui.ImVec2(0, 0), imgui.ChildFlags_.borders):
        if not entries:
            imgui.text_disabled("none yet")
        for e, applied in entries:
            text = f"#{e.id}  {e.op.describe()}  {e.count}" + (f"  {e.label}" if e.label else "")
            if applied:
                imgui.text(text[:80])
            else:
                imgui.text_disabled(f"{text[:70]}  (undone)")
        if ui.cache.get("edit_list_len") != len(entries):  # a new edit: scroll to the newest
            ui.cache["edit_list_len"] = len(entries)
            imgui.set_scroll_here_y(1.0)
    imgui.end_child()
    ui.mark("edit_list")


def draw(ui: PanelContext) -> None:
    ed = ui.edits
    if ed is None:
        return
    if ed.session is None:
        error_text(ed.error or "editing is not available")
        return
    _selection(ui)
    _actions(ui)
    _history(ui)
