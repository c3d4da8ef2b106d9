"""The error-vs-run-time report: PSNR over training seconds, for the views a run has -- seen and
unseen evaluation views (ground truth from other cameras) and the seen-view validation (held-out
frames of the video, or the training-view fit)."""

from __future__ import annotations

from pathlib import Path

from ..atomic import atomic_output
from .metrics_log import MetricsLog

# (record key, column title, width, decimals)
COLUMNS = (("seen_psnr", "seen PSNR", 10, 2), ("seen_ssim", "seen SSIM", 10, 4), ("unseen_psnr", "unseen PSNR", 12, 2),
           ("unseen_ssim", "unseen SSIM", 12, 4), ("val_psnr", "val PSNR", 9, 2), ("val_ssim", "val SSIM", 9, 4),
           ("val_alpha_iou", "val alpha IoU", 14, 4))
# (record key prefix, label, colour) of the curves
CURVES = (("seen", "seen views", "tab:orange"), ("unseen", "unseen views", "tab:blue"),
          ("val", "validation frames", "tab:green"))


def error_vs_time_table(records: list[dict]) -> str:
    """A text table of the evaluation records, with the columns any record has a value for."""
    cols = [c for c in COLUMNS if any(isinstance(r.get(c[0]), (int, float)) for r in records)]
    lines = [f"{'seconds':>8} {'step':>7} {'stage':>5} " + " ".join(f"{t:>{w}}" for _, t, w, _ in cols)]
    for r in records:
        cells = [f"{r[k]:>{w}.{p}f}" if isinstance(r.get(k), (int, float)) else f"{'-':>{w}}" for k, _, w, p in cols]
        lines.append(f"{r['elapsed']:>8.0f} {r['step']:>7d} {r.get('stage', 1):>5} " + " ".join(cells))
    kinds = sorted({r["val_kind"] for r in records if r.get("val_kind")})
    if kinds:
        lines.append(f"(val: {', '.join(kinds)})")
    return "\n".join(lines)


def plot_error_vs_time(run_dir: str | Path, out: str | Path | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    records = MetricsLog(run_dir / "metrics.jsonl").read("eval")
    if not records:
        raise ValueError(f"{run_dir / 'metrics.jsonl'}: no evaluation records to plot")
    out = Path(out) if out else run_dir / "error_vs_time.png"
    t = [r["elapsed"] for r in records]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for key, label, color in CURVES:
        if not any(isinstance(r.get(f"{key}_psnr"), (int, float)) for r in records):
            continue
        if key == "val":
            label += f" ({records[-1].get('val_kind', 'held out')})"
        axes[0].plot(t, [r.get(f"{key}_psnr") for r in records], "o-", ms=3, label=label, color=color)
        axes[1].plot(t, [r.get(f"{key}_ssim") for r in records], "o-", ms=3, label=label, color=color)
    stage2 = [r["elapsed"] for r in records if r.get("stage") == 2]
    for ax, name in zip(axes, ("PSNR (dB)", "SSIM")):
        if stage2:
            ax.axvline(stage2[0], color="gray", ls="--", lw=1, label="Stage II starts")
        ax.set_xlabel("training time (s)")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{run_dir.name}: error against run time", fontsize=10)
    fig.tight_layout()
    with atomic_output(out) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return out
