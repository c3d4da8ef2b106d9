"""Stage II panel (control): start it, the canonical:observation and given:dual-space ratios, the
visibility threshold, the λ_SDS schedule (Eq. 14) with its curve, and the prior."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from .common import error_text, plot, wrapped_hint
from .context import PanelContext

# Stage II settings the panel edits (Stage2Config fields)
SETTINGS = ("given_view_ratio", "canonical_ratio", "lambda_sds", "sds_t0", "sds_k", "progressive",
            "visibility_threshold", "prior", "prior_path")


def default_settings() -> dict:
    from reconstruct.stage2.config import Stage2Config

    cfg = Stage2Config()
    return {k: getattr(cfg, k) for k in SETTINGS}


def sds_curve(settings: dict, steps: int, epoch_steps: float | None = None, points: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """λ_SDS over Stage II steps 0..steps for the panel's settings (Stage2Config.sds_weight)."""
    from reconstruct.stage2.config import Stage2Config

    extra = {} if epoch_steps is None else {"epoch_steps": epoch_steps}
    cfg = Stage2Config(**{**settings, "prior": "builtin", "prior_path": None, **extra})
    x = np.linspace(0.0, float(max(steps, 1)), points)
    return x, np.asarray([cfg.sds_weight(int(v)) for v in x], np.float64)


def draw(ui: PanelContext) -> None:
    from reconstruct.stage2.config import Stage2Config

    st, s = ui.status, ui.stage2_settings
    changes = {}
    if st.stage < 2:
        wrapped_hint("Settings below are used when Stage II starts; after that they change the running "
                     "Stage II between steps.")
        if imgui.button("Start Stage II"):
            ui.actions.start_stage2()
        ui.mark("start_stage2")
    else:
        imgui.text(f"Stage II step {st.stage_step}")
    for key, label, lo, hi in (("canonical_ratio", "canonical : obs.", 0.0, 1.0),
                               ("given_view_ratio", "given : dual space", 0.0, 1.0),
                               ("visibility_threshold", "visibility thresh.", 0.05, 0.95)):
        ch, v = imgui.slider_float(label, float(s[key]), lo, hi, "%.2f")
        ui.mark(key)
        if ch:
            changes[key] = round(v, 3)
    imgui.separator_text("λ_SDS(t) = λ0 / 2^floor((t - t0) / k)")
    for key, label, step, fast, fmt, lo in (("lambda_sds", "λ_SDS,0", 0.05, 0.1, "%.3f", 0.0),
                                            ("sds_t0", "t0 (epochs)", 10.0, 50.0, "%.0f", 0.0),
                                            ("sds_k", "k (epochs)", 10.0, 50.0, "%.0f", 1.0)):
        ch, v = imgui.input_float(label, float(s[key]), step, fast, fmt)
        if ch:
            changes[key] = max(lo, v)
    ch, v = imgui.checkbox("progressive (halving)", bool(s["progressive"]))
    if ch:
        changes["progressive"] = v
    running = st.stage2 or {}
    default = Stage2Config()
    epoch_steps = float(running.get("epoch_steps", default.epoch_steps))
    iters = int(running.get("iters", default.iters))
    try:
        key = (tuple(sorted((k, str(v)) for k, v in s.items())), iters, epoch_steps)
        if ui.cache.get("sds", (None,))[0] != key:
            ui.cache["sds"] = (key, sds_curve(s, iters, epoch_steps))
        x, y = ui.cache["sds"][1]
        plot("λ_SDS over Stage II steps##sds", "λ_SDS", [("λ_SDS", x, y)], imgui.get_content_region_avail().x,
             marker=float(st.stage_step) if st.stage >= 2 else None)
    except ValueError as exc:
        error_text(str(exc))
    labels = ["built-in (appearance propagation)", "Zero123 (diffusers folder)"]
    ch, idx = imgui.combo("prior", 0 if s["prior"] == "builtin" else 1, labels)
    if ch:
        changes["prior"] = ("builtin", "zero123")[idx]
    if s["prior"] == "zero123" or changes.get("prior") == "zero123":
        ch, path = imgui.input_text("model folder", s.get("prior_path") or "")
        if ch:
            changes["prior_path"] = path or None
        if not (changes.get("prior_path") or s.get("prior_path")):
            imgui.text_disabled("a diffusers-format Zero123 folder is needed")
    if changes:
        ui.actions.push_stage2_settings(**changes)
    if st.stage2_message:
        error_text(st.stage2_message)
    if st.candidate_views:
        imgui.text(f"{st.unseen_views} unseen of {st.candidate_views} candidate views")
