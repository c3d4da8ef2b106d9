"""Export panel: orbit / video poses / novel sequence videos with a progress bar, screenshots."""

from __future__ import annotations

from imgui_bundle import imgui

from ..export_job import FORMATS, KIND_LABELS, KINDS
from .common import error_text
from .context import PanelContext


def draw(ui: PanelContext) -> None:
    ex = ui.export
    e, job = ex.settings, ex.job
    busy = job is not None and not job.done
    imgui.begin_disabled(busy)
    ch, idx = imgui.combo("what", KINDS.index(e.kind), [KIND_LABELS[k] for k in KINDS])
    if ch:
        e.kind = KINDS[idx]
    if e.kind != "poses":
        ch, v = imgui.input_int("frames", e.frames, 1, 10)
        if ch:
            e.frames = max(1, v)
    ch, v = imgui.input_int("size (px)", e.size, 16, 64)
    if ch:
        e.size = max(2, v)
    ch, v = imgui.input_float("fps", e.fps, 1.0, 5.0, "%.0f")
    if ch:
        e.fps = max(1.0, v)
    suffix = ".gif" if e.out.lower().endswith(".gif") else ".mp4"
    for k, fmt in enumerate(FORMATS):
        if k:
            imgui.same_line()
        if imgui.radio_button(fmt[1:], suffix == fmt):
            stem = e.out[: -len(suffix)] if e.out.lower().endswith(suffix) else e.out
            e.out = stem + fmt
    ch, path = imgui.input_text("file", e.out)
    ui.mark("export_path")
    if ch:
        e.out = path
    imgui.text_disabled(f"mode: {ui.view.mode.label} (the live view's)")
    if imgui.button("Export video"):
        ui.actions.start_export()
    ui.mark("export")
    imgui.end_disabled()
    if busy:
        imgui.same_line()
        if imgui.button("Cancel"):
            ui.actions.cancel_export()
    if job is not None:
        imgui.progress_bar(job.progress, imgui.ImVec2(-1, 0), f"{job.written}/{job.total or '?'} frames")
        if job.done and job.result is not None:
            imgui.text_disabled(f"wrote {job.result}")
    if imgui.button("Screenshot (PNG)"):
        ui.actions.request_screenshot(ui.actions.screenshot_path())
    if ex.saved_screenshots:
        imgui.same_line()
        imgui.text_disabled(ex.saved_screenshots[-1][-40:])
    if ex.message:
        error_text(ex.message)
