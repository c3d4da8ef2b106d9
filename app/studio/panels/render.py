"""Render panel: render mode, observation / canonical space, ground truth beside, camera snaps."""

from __future__ import annotations

from imgui_bundle import imgui

from renderer.render_modes import RenderMode

from .context import PanelContext

MODES = list(RenderMode)


def draw(ui: PanelContext) -> None:
    view = ui.view
    opened = imgui.begin_combo("mode", view.mode.label)
    ui.mark("mode")
    if opened:
        for mm in MODES:
            if imgui.selectable(mm.label, mm is view.mode)[0]:
                ui.actions.set_mode(mm)
            ui.mark(f"mode_{mm.value}")
        imgui.end_combo()
    if imgui.radio_button("observation", view.space == "observation"):
        ui.actions.set_space("observation")
    imgui.same_line()
    if imgui.radio_button("canonical", view.space == "canonical"):
        ui.actions.set_space("canonical")
    ch, v = imgui.checkbox("side by side with ground truth", view.show_ground_truth)
    if ch:
        view.show_ground_truth = v
    if imgui.button("training camera"):
        ui.actions.snap_to_training_camera()
    imgui.same_line()
    if imgui.button("frame avatar"):
        ui.actions.frame_avatar()
    views = ui.scene.eval_views
    if views:
        imgui.text("evaluation cameras (S seen, U unseen):")
        for k, v in enumerate(views):
            if k % 4:
                imgui.same_line()
            if imgui.small_button(f"{'S' if v.seen else 'U'} {v.azimuth_deg:+.0f}##ev{k}"):
                ui.actions.snap_to_eval_view(k)
    imgui.text_disabled("drag: orbit, right-drag: pan, wheel: zoom, H: hide")
