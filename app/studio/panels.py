"""The imgui panels: Training, Render and Pose (Stage II controls come later)."""

from __future__ import annotations

import math

import numpy as np
from imgui_bundle import imgui

from renderer.render_modes import RenderMode

MODES = list(RenderMode)
PANEL_WIDTH = 300


def _finite_series(values) -> np.ndarray:
    a = np.asarray([v for v in values if math.isfinite(v)], np.float32)
    return a[-400:]


def training_panel(app) -> None:
    t, s = app.trainer, app.session
    c = app.controls.get()
    snap = s.snapshots.latest()
    m = dict(snap.metrics)
    status = "error" if t.error else "finished" if s.done else "paused" if c.paused else "training"
    imgui.text(f"Stage I  -  {status}")
    imgui.text(f"step {s.step_count} / {s.config.iters}   {t.its:5.1f} it/s")
    imgui.text(f"elapsed {s.elapsed:7.1f} s   {s.model.num_gaussians} Gaussians")
    for key in ("loss", "rgb", "ssim", "normal", "lpips", "psnr_train"):
        if key in m:
            imgui.text(f"  {key:<13}{m[key]:.5f}" if key != "psnr_train" else f"  {key:<13}{m[key]:.2f} dB")
    for key in ("seen_psnr", "unseen_psnr"):
        if key in m:
            imgui.text(f"  {key:<13}{m[key]:.2f} dB")
    if imgui.button("Resume" if c.paused else "Pause"):
        app.controls.update(paused=not c.paused)
    imgui.same_line()
    imgui.begin_disabled(not c.paused)
    if imgui.button("Step"):
        app.controls.update(single_step=True)
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(s.run_dir is None)
    if imgui.button("Save"):
        app.controls.update(save=True)
    imgui.end_disabled()
    if s.run_dir is None:
        imgui.text_disabled("(no run folder: --run RUN to save)")
    elif t.last_saved:
        imgui.text_disabled(f"saved {t.last_saved}")
    hist = t.history()
    if hist:
        width = imgui.get_content_region_avail().x
        loss = _finite_series(r.loss for r in hist)
        if len(loss):
            imgui.plot_lines("##loss", loss, overlay_text=f"loss {loss[-1]:.4f}", graph_size=imgui.ImVec2(width, 50))
        for name, series in (("seen PSNR", [r.seen_psnr for r in hist]), ("unseen PSNR", [r.unseen_psnr for r in hist])):
            v = _finite_series(series)
            if len(v):
                imgui.plot_lines(f"##{name}", v, overlay_text=f"{name} {v[-1]:.2f} dB",
                                 graph_size=imgui.ImVec2(width, 50))
    if t.error:
        imgui.text_colored(imgui.ImVec4(1, 0.4, 0.4, 1), t.error.strip().splitlines()[-1][:200])


def render_panel(app) -> None:
    idx = MODES.index(app.mode)
    changed, idx = imgui.combo("mode", idx, [mm.label for mm in MODES])
    if changed:
        app.set_mode(MODES[idx])
    c = app.controls.get()
    if imgui.radio_button("observation", c.space == "observation"):
        app.set_space("observation")
    imgui.same_line()
    if imgui.radio_button("canonical", c.space == "canonical"):
        app.set_space("canonical")
    if imgui.button("training camera"):
        app.snap_to_training_camera()
    imgui.same_line()
    if imgui.button("frame avatar"):
        app.frame_avatar()
    views = app.scene.eval_views
    if views:
        imgui.text("evaluation cameras:")
        for k, v in enumerate(views):
            if k % 3:
                imgui.same_line()
            if imgui.small_button(f"{'S' if v.seen else 'U'} {v.azimuth_deg:+.0f}##ev{k}"):
                app.snap_to_eval_view(k)
    imgui.text_disabled("drag: orbit, right-drag: pan, wheel: zoom, H: hide panels")


def pose_panel(app) -> None:
    n = len(app.scene.frames)
    changed, i = imgui.slider_int("frame", app.frame_index, 0, n - 1)
    if changed:
        app.set_frame(i)
    if imgui.button("Pause##play" if app.playing else "Play"):
        app.playing = not app.playing
    imgui.same_line()
    imgui.text(f"{app.scene.fps:g} fps, {n} frames")


def draw_panels(app) -> None:
    y = 10.0
    for title, body, height in (("Training", training_panel, 330), ("Render", render_panel, 200),
                                ("Pose", pose_panel, 90)):
        imgui.set_next_window_pos(imgui.ImVec2(10, y), imgui.Cond_.first_use_ever)
        imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, height), imgui.Cond_.first_use_ever)
        y += height + 8
        if imgui.begin(title)[0]:
            body(app)
        imgui.end()
