"""Training panel (control): stage, step, speed, pause / step / save, loss and PSNR curves."""

from __future__ import annotations

import math

import numpy as np
from imgui_bundle import imgui

from .common import error_text, finite_xy, plot
from .context import PanelContext

MAX_PLOT_POINTS = 1500


def history_series(ui: PanelContext):
    """(loss, seen PSNR, unseen PSNR, validation PSNR) as (x, y) arrays over training time, rebuilt only when the
    history grew (and thinned to at most MAX_PLOT_POINTS), or None before the first row."""
    key = ("history", ui.history_len)
    cached = ui.cache.get("history")
    if cached is not None and cached[0] == key:
        return cached[1]
    hist = ui.history()
    if not hist:
        return None
    a = np.asarray([(r.elapsed, r.loss, r.seen_psnr, r.unseen_psnr, r.val_psnr) for r in hist], np.float64)
    if len(a) > MAX_PLOT_POINTS:
        a = a[np.linspace(0, len(a) - 1, MAX_PLOT_POINTS).astype(int)]
    series = tuple(finite_xy(a[:, 0], a[:, k]) for k in (1, 2, 3, 4))
    ui.cache["history"] = (key, series)
    return series


def draw(ui: PanelContext) -> None:
    st = ui.status
    state = "error" if st.error else "finished" if st.done else "paused" if st.paused else "training"
    imgui.text(f"Stage {'I' * st.stage}  -  {state}")
    if st.stage >= 2:
        imgui.text(f"step {st.step}  (Stage II step {st.stage_step} / {st.planned_steps})")
    else:
        imgui.text(f"step {st.step} / {st.planned_steps}")
    imgui.text(f"{st.its:5.2f} it/s   GUI {ui.fps:4.1f} fps")
    imgui.text(f"elapsed {st.elapsed:7.1f} s   {st.num_gaussians} Gaussians")
    if imgui.button("Resume" if st.paused else "Pause"):
        ui.actions.pause(not st.paused)
    ui.mark("pause")
    imgui.same_line()
    imgui.begin_disabled(not st.paused)
    if imgui.button("Step"):
        ui.actions.single_step()
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not st.has_run_folder)
    if imgui.button("Save checkpoint"):
        ui.actions.save_checkpoint()
    imgui.end_disabled()
    if not st.has_run_folder:
        imgui.text_disabled("(no run folder: --run RUN to save)")
    elif st.last_saved:
        imgui.text_disabled(f"saved {st.last_saved}")
    series = history_series(ui)
    if series is not None:
        width = imgui.get_content_region_avail().x
        loss, seen, unseen, val = series
        plot("loss##plot", "loss", [("loss", *loss)], width)
        curves = [(name, *xy) for name, xy in (("seen", seen), ("unseen", unseen), ("held-out", val)) if len(xy[0])]
        plot("PSNR (dB)##plot", "dB", curves or [("seen", *seen)], width)
        imgui.text_disabled("x: training time (s)")
        first = True
        for key in ("seen_psnr", "unseen_psnr", "val_psnr"):
            v = st.metrics.get(key)
            if isinstance(v, (int, float)) and math.isfinite(v):
                if not first:
                    imgui.same_line()
                imgui.text(f"{key.split('_')[0]} {v:.2f} dB")
                first = False
    if st.error:
        error_text(st.error.strip().splitlines()[-1][:300])
