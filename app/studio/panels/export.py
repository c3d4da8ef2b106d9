"""Export panel: orbit / video poses / novel sequence / motion file videos with a progress bar, the
Gaussians as 3DGS .ply, .compressed.ply, .splat or .spz (current frame, canonical space, or the Pose
panel's sequence as a folder), screenshots."""

from __future__ import annotations

from imgui_bundle import imgui

from reconstruct.gaussian_files import FORMATS as SPLAT_FORMATS

from ..export_job import FORMATS, KIND_LABELS, KINDS, PLY_KINDS
from .common import error_text
from .context import PanelContext

UPS = (("y_down", "y down (viewers)"), ("z_up", "z up (ours)"))


def _retarget_suffix(out: str, kind: str, splat_format: str = "ply") -> str:
    """The file field after choosing ``kind``: the splat format's suffix (.ply ...) for one file, no
    suffix for a folder of them, .mp4/.gif kept (or .mp4) for videos."""
    low = out.lower()
    known = FORMATS + tuple(sorted(("." + f for f in SPLAT_FORMATS), key=len, reverse=True))  # longer first
    stem = next((out[: -len(s)] for s in known if low.endswith(s)), out)
    if kind == "ply_sequence":
        return stem if stem.endswith("_frames") else stem + "_frames"
    stem = stem.removesuffix("_frames")
    if kind in PLY_KINDS:
        return stem + "." + splat_format
    return stem + (".gif" if low.endswith(".gif") else ".mp4")


def _video_settings(ui: PanelContext) -> None:
    e = ui.export.settings
    if e.kind in ("orbit", "walk", "arms_up"):
        ch, v = imgui.input_int("frames", e.frames, 1, 10)
        if ch:
            e.frames = max(1, v)
    ch, v = imgui.input_int("size (px)", e.size, 16, 64)
    if ch:
        e.size = max(2, v)
    if e.kind == "motion":
        loaded = ui.view.motion.loaded
        imgui.text_disabled(f"{loaded.name}: {len(loaded)} frames at {loaded.fps:g} fps" if loaded is not None
                            else "open a motion file in the Pose panel")
    else:
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


def _ply_settings(ui: PanelContext) -> None:
    e = ui.export.settings
    view = ui.view
    if e.kind == "ply_frame":
        imgui.text_disabled(f"video frame {view.frame_index} (the Pose panel's)")
    elif e.kind == "ply_sequence":
        src = view.pose_source
        if src == "motion" and view.motion.loaded is not None:
            what = f"{view.motion.loaded.name}, {len(view.motion.loaded)} frames"
        elif src in ("walk", "arms_up"):
            ch, v = imgui.input_int("frames", e.frames, 1, 10)
            if ch:
                e.frames = max(2, v)
            what = f"{src}, {e.frames} frames"
        else:
            what = f"the video's {len(ui.scene.frames)} poses"
        imgui.text_disabled(f"sequence: {what}")
        ch, v = imgui.checkbox("overwrite the folder", e.overwrite)
        if ch:
            e.overwrite = v
    for k, (up, label) in enumerate(UPS):
        if k:
            imgui.same_line()
        if imgui.radio_button(label, e.up == up):
            e.up = up
    # .spz and .sog: about 20 times smaller than .ply, quantised (a combo: five radio buttons overflow)
    ch, idx = imgui.combo("format", SPLAT_FORMATS.index(e.splat_format), list(SPLAT_FORMATS))
    ui.mark("export_splat_format")
    if ch:
        e.splat_format = SPLAT_FORMATS[idx]
        e.out = _retarget_suffix(e.out, e.kind, e.splat_format)


def draw(ui: PanelContext) -> None:
    ex = ui.export
    e, job = ex.settings, ex.job
    busy = job is not None and not job.done
    imgui.begin_disabled(busy)
    ch, idx = imgui.combo("what", KINDS.index(e.kind), [KIND_LABELS[k] for k in KINDS])
    ui.mark("export_kind")
    if ch:
        e.kind = KINDS[idx]
        e.out = _retarget_suffix(e.out, e.kind, e.splat_format)
    if e.is_ply:
        _ply_settings(ui)
    else:
        _video_settings(ui)
    ch, path = imgui.input_text("folder" if e.kind == "ply_sequence" else "file", e.out)
    ui.mark("export_path")
    if ch:
        e.out = path
    if not e.is_ply:
        imgui.text_disabled(f"mode: {ui.view.mode.label} (the live view's)")
    if imgui.button("Export .ply" if e.is_ply else "Export video"):
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
