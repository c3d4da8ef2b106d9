"""The imgui panels, nerfstudio-style: Training (control), Stage II, Render, Pose and Export.

Panels never touch the training session directly: they write ``Controls`` (the trainer thread
applies them between steps) or app state (camera, render mode, export jobs). After each widget
that a GUI test drives with real input, ``app.mark(name)`` records the widget's rectangle.
"""

from __future__ import annotations

import math

import numpy as np
from imgui_bundle import imgui, implot

from renderer.render_modes import RenderMode

from .export_job import FORMATS, KIND_LABELS, KINDS

MODES = list(RenderMode)
PANEL_WIDTH = 320
PLOT_HEIGHT = 95
ERROR_RGBA = (1.0, 0.45, 0.4, 1.0)
POSE_SOURCES = ("video", "walk", "arms_up")
POSE_LABELS = {"video": "video poses", "walk": "novel: walk cycle", "arms_up": "novel: arms up"}


def _finite_xy(xs, ys) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(xs, np.float64)
    y = np.asarray(ys, np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    return np.ascontiguousarray(x[ok]), np.ascontiguousarray(y[ok])


def _error(text: str) -> None:
    imgui.push_text_wrap_pos(0.0)
    imgui.text_colored(imgui.ImVec4(*ERROR_RGBA), text)
    imgui.pop_text_wrap_pos()


def _plot(title: str, y_label: str, series: list[tuple[str, np.ndarray, np.ndarray]], width: float,
          marker: float | None = None) -> None:
    """One implot plot of ``series`` (label, x, y); axes fit the data each frame."""
    flags = implot.Flags_.no_menus.value | implot.Flags_.no_box_select.value
    if len(series) == 1:
        flags |= implot.Flags_.no_legend.value
    if implot.begin_plot(title, imgui.ImVec2(width, PLOT_HEIGHT), flags):
        fit = implot.AxisFlags_.auto_fit.value
        implot.setup_axes("", y_label, fit, fit)
        implot.setup_legend(implot.Location_.north_east.value)
        for label, x, y in series:
            if len(x):
                implot.plot_line(label, x, y)
        if marker is not None:
            implot.plot_inf_lines("##now", np.asarray([marker], np.float64))
        implot.end_plot()


# ----------------------------------------------------------------------------- training
MAX_PLOT_POINTS = 1500


def _history_series(app):
    """(loss, seen PSNR, unseen PSNR) as (x, y) arrays over training time, rebuilt only when the
    history grew (and thinned to at most MAX_PLOT_POINTS), or None before the first row."""
    n = app.trainer.history_len
    key = ("history", n, id(app.session))
    cached = app.cache.get("history")
    if cached is not None and cached[0] == key:
        return cached[1]
    hist = app.trainer.history()
    if not hist:
        return None
    a = np.asarray([(r.elapsed, r.loss, r.seen_psnr, r.unseen_psnr) for r in hist], np.float64)
    if len(a) > MAX_PLOT_POINTS:
        a = a[np.linspace(0, len(a) - 1, MAX_PLOT_POINTS).astype(int)]
    series = tuple(_finite_xy(a[:, 0], a[:, k]) for k in (1, 2, 3))
    app.cache["history"] = (key, series)
    return series


def training_panel(app) -> None:
    t, s = app.trainer, app.session
    c = app.controls.get()
    stage = s.stage
    status = "error" if t.error else "finished" if s.done else "paused" if c.paused else "training"
    imgui.text(f"Stage {'I' * stage}  -  {status}")
    if stage >= 2:
        imgui.text(f"step {s.step_count}  (Stage II step {getattr(s, 'stage2_step', 0)})")
    else:
        imgui.text(f"step {s.step_count} / {s.config.iters}")
    imgui.text(f"{t.its:5.2f} it/s   GUI {app.fps:4.1f} fps")
    imgui.text(f"elapsed {s.elapsed:7.1f} s   {s.model.num_gaussians} Gaussians")
    if imgui.button("Resume" if c.paused else "Pause"):
        app.controls.update(paused=not c.paused)
    app.mark("pause")
    imgui.same_line()
    imgui.begin_disabled(not c.paused)
    if imgui.button("Step"):
        app.controls.update(single_step=True)
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(s.run_dir is None)
    if imgui.button("Save checkpoint"):
        app.controls.update(save=True)
    imgui.end_disabled()
    if s.run_dir is None:
        imgui.text_disabled("(no run folder: --run RUN to save)")
    elif t.last_saved:
        imgui.text_disabled(f"saved {t.last_saved}")
    series = _history_series(app)
    if series is not None:
        width = imgui.get_content_region_avail().x
        loss, seen, unseen = series
        _plot("loss##plot", "loss", [("loss", *loss)], width)
        _plot("PSNR (dB)##plot", "dB", [("seen", *seen), ("unseen", *unseen)], width)
        imgui.text_disabled("x: training time (s)")
        m = s.latest
        for key in ("seen_psnr", "unseen_psnr"):
            v = m.get(key)
            if isinstance(v, (int, float)) and math.isfinite(v):
                imgui.same_line() if key == "unseen_psnr" else None
                imgui.text(f"{key.split('_')[0]} {v:.2f} dB")
    if t.error:
        _error(t.error.strip().splitlines()[-1][:300])


# ----------------------------------------------------------------------------- Stage II
def _stage2_defaults() -> dict:
    from reconstruct.stage2.config import Stage2Config

    from .trainer_thread import STAGE2_SETTINGS

    cfg = Stage2Config()
    return {k: getattr(cfg, k) for k in STAGE2_SETTINGS}


def sds_curve(settings: dict, steps: int, epoch_steps: float | None = None, points: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """λ_SDS over Stage II steps 0..steps for the panel's settings (Stage2Config.sds_weight)."""
    from reconstruct.stage2.config import Stage2Config

    extra = {} if epoch_steps is None else {"epoch_steps": epoch_steps}
    cfg = Stage2Config(**{**settings, "prior": "builtin", "prior_path": None, **extra})
    x = np.linspace(0.0, float(max(steps, 1)), points)
    return x, np.asarray([cfg.sds_weight(int(v)) for v in x], np.float64)


def stage2_panel(app) -> None:
    s, t = app.session, app.trainer
    st = app.stage2_settings
    stage = s.stage
    changed = False
    live = getattr(s, "stage2", None)
    if stage < 2:
        imgui.push_text_wrap_pos(0.0)
        imgui.text_disabled("Settings below are used when Stage II starts; after that they change the running "
                            "Stage II between steps.")
        imgui.pop_text_wrap_pos()
        if imgui.button("Start Stage II"):
            app.controls.update(start_stage2=True)
        app.mark("start_stage2")
    else:
        imgui.text(f"Stage II step {getattr(s, 'stage2_step', 0)}")
    ch, v = imgui.slider_float("canonical : obs.", float(st["canonical_ratio"]), 0.0, 1.0, "%.2f")
    app.mark("canonical_ratio")
    if ch:
        st["canonical_ratio"], changed = round(v, 3), True
    ch, v = imgui.slider_float("given : dual space", float(st["given_view_ratio"]), 0.0, 1.0, "%.2f")
    app.mark("given_view_ratio")
    if ch:
        st["given_view_ratio"], changed = round(v, 3), True
    ch, v = imgui.slider_float("visibility thresh.", float(st["visibility_threshold"]), 0.05, 0.95, "%.2f")
    app.mark("visibility_threshold")
    if ch:
        st["visibility_threshold"], changed = round(v, 3), True
    imgui.separator_text("λ_SDS(t) = λ0 / 2^floor((t - t0) / k)")
    ch, v = imgui.input_float("λ_SDS,0", float(st["lambda_sds"]), 0.05, 0.1, "%.3f")
    if ch:
        st["lambda_sds"], changed = max(0.0, v), True
    ch, v = imgui.input_float("t0 (epochs)", float(st["sds_t0"]), 10.0, 50.0, "%.0f")
    if ch:
        st["sds_t0"], changed = max(0.0, v), True
    ch, v = imgui.input_float("k (epochs)", float(st["sds_k"]), 10.0, 50.0, "%.0f")
    if ch:
        st["sds_k"], changed = max(1.0, v), True
    ch, v = imgui.checkbox("progressive (halving)", bool(st["progressive"]))
    if ch:
        st["progressive"], changed = v, True
    from reconstruct.stage2.config import Stage2Config

    default = Stage2Config()
    epoch_steps = float(getattr(live, "epoch_steps", default.epoch_steps))
    iters = int(getattr(live, "iters", default.iters))
    step2 = getattr(s, "stage2_step", None) if stage >= 2 else None
    try:
        key = (tuple(sorted((k, str(v)) for k, v in st.items())), iters, epoch_steps)
        if app.cache.get("sds", (None,))[0] != key:
            app.cache["sds"] = (key, sds_curve(st, iters, epoch_steps))
        x, y = app.cache["sds"][1]
        _plot("λ_SDS over Stage II steps##sds", "λ_SDS", [("λ_SDS", x, y)], imgui.get_content_region_avail().x,
              marker=float(step2) if step2 is not None else None)
    except ValueError as exc:
        _error(str(exc))
    prior = st["prior"]
    labels = ["built-in (appearance propagation)", "Zero123 (diffusers folder)"]
    idx = 0 if prior == "builtin" else 1
    ch, idx = imgui.combo("prior", idx, labels)
    if ch:
        st["prior"], changed = ("builtin", "zero123")[idx], True
    if st["prior"] == "zero123":
        ch, path = imgui.input_text("model folder", st.get("prior_path") or "")
        if ch:
            st["prior_path"], changed = (path or None), True
        if not st.get("prior_path"):
            imgui.text_disabled("a diffusers-format Zero123 folder is needed")
    if changed:
        app.push_stage2_settings()
    if t.stage2_message:
        _error(t.stage2_message)
    views = getattr(s, "selected_views", None) if stage >= 2 else None
    if views:
        unseen = [v for v in views if v.unseen]
        imgui.text(f"{len(unseen)} unseen of {len(views)} candidate views")


# ----------------------------------------------------------------------------- render
def render_panel(app) -> None:
    opened = imgui.begin_combo("mode", app.mode.label)
    app.mark("mode")
    if opened:
        for mm in MODES:
            if imgui.selectable(mm.label, mm is app.mode)[0]:
                app.set_mode(mm)
            app.mark(f"mode_{mm.value}")
        imgui.end_combo()
    c = app.controls.get()
    if imgui.radio_button("observation", c.space == "observation"):
        app.set_space("observation")
    imgui.same_line()
    if imgui.radio_button("canonical", c.space == "canonical"):
        app.set_space("canonical")
    ch, v = imgui.checkbox("side by side with ground truth", app.show_ground_truth)
    if ch:
        app.show_ground_truth = v
    if imgui.button("training camera"):
        app.snap_to_training_camera()
    imgui.same_line()
    if imgui.button("frame avatar"):
        app.frame_avatar()
    views = app.scene.eval_views
    if views:
        imgui.text("evaluation cameras (S seen, U unseen):")
        for k, v in enumerate(views):
            if k % 4:
                imgui.same_line()
            if imgui.small_button(f"{'S' if v.seen else 'U'} {v.azimuth_deg:+.0f}##ev{k}"):
                app.snap_to_eval_view(k)
    imgui.text_disabled("drag: orbit, right-drag: pan, wheel: zoom, H: hide")


# ----------------------------------------------------------------------------- pose
def pose_panel(app) -> None:
    idx = POSE_SOURCES.index(app.pose_source)
    ch, idx = imgui.combo("poses", idx, [POSE_LABELS[p] for p in POSE_SOURCES])
    if ch:
        app.set_pose_source(POSE_SOURCES[idx])
    n = app.num_pose_frames
    changed, i = imgui.slider_int("frame", app.pose_frame, 0, n - 1)
    app.mark("frame")
    if changed:
        app.set_pose_frame(i)
    if imgui.button("Pause##play" if app.playing else "Play"):
        app.playing = not app.playing
    app.mark("play")
    imgui.same_line()
    imgui.text(f"{app.scene.fps:g} fps, {n} frames")


# ----------------------------------------------------------------------------- export
def export_panel(app) -> None:
    e = app.export_settings
    job = app.export_job
    busy = job is not None and not job.done
    imgui.begin_disabled(busy)
    idx = KINDS.index(e.kind)
    ch, idx = imgui.combo("what", idx, [KIND_LABELS[k] for k in KINDS])
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
    app.mark("export_path")
    if ch:
        e.out = path
    imgui.text_disabled(f"mode: {app.mode.label} (the live view's)")
    if imgui.button("Export video"):
        app.start_export()
    app.mark("export")
    imgui.end_disabled()
    if busy:
        imgui.same_line()
        if imgui.button("Cancel"):
            job.cancel()
    if job is not None:
        frac = job.progress
        imgui.progress_bar(frac, imgui.ImVec2(-1, 0), f"{job.written}/{job.total or '?'} frames")
        if job.done and job.result is not None:
            imgui.text_disabled(f"wrote {job.result}")
    if imgui.button("Screenshot (PNG)"):
        app.request_screenshot(app.screenshot_path())
    if app.saved_screenshots:
        imgui.same_line()
        imgui.text_disabled(app.saved_screenshots[-1][-40:])
    if app.export_message:
        _error(app.export_message)


PANELS = (("Training", training_panel, 345), ("Stage II", stage2_panel, 427), ("Render", render_panel, 200),
          ("Pose", pose_panel, 110), ("Export", export_panel, 300))


def draw_panels(app) -> None:
    """Training and Stage II in the left column, Render / Pose / Export on the right."""
    fw = imgui.get_io().display_size.x
    cols = {"Training": 0, "Stage II": 0, "Render": 1, "Pose": 1, "Export": 1}
    ys = [10.0, 10.0]
    for title, body, height in PANELS:
        col = cols[title]
        x = 10.0 if col == 0 else max(10.0 + PANEL_WIDTH + 8, fw - PANEL_WIDTH - 10)
        imgui.set_next_window_pos(imgui.ImVec2(x, ys[col]), imgui.Cond_.first_use_ever)
        imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, height), imgui.Cond_.first_use_ever)
        ys[col] += height + 8
        if imgui.begin(title)[0]:
            imgui.push_item_width(PANEL_WIDTH * 0.52)
            body(app)
            imgui.pop_item_width()
        imgui.end()


def draw_error_window(message: str) -> bool:
    """The scene-load error, centred. Returns True when the user asks to quit."""
    io = imgui.get_io()
    w = min(640.0, io.display_size.x - 20)
    imgui.set_next_window_pos(imgui.ImVec2(0.5 * (io.display_size.x - w), 40), imgui.Cond_.always)
    imgui.set_next_window_size(imgui.ImVec2(w, 0), imgui.Cond_.always)
    quit_ = False
    if imgui.begin("Could not open the scene", None, imgui.WindowFlags_.no_collapse)[0]:
        _error(message)
        imgui.spacing()
        imgui.text_disabled("Start again with --scene SCENE (a scene folder or synthetic:seed=S).")
        quit_ = imgui.button("Quit")
    imgui.end()
    return quit_
