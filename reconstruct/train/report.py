"""The error-vs-run-time report: PSNR over training seconds, seen and unseen views."""

from __future__ import annotations

from pathlib import Path

from .metrics_log import MetricsLog
from ..atomic import atomic_output


def error_vs_time_table(records: list[dict]) -> str:
    lines = [f"{'seconds':>8} {'step':>7} {'stage':>5} {'seen PSNR':>10} {'seen SSIM':>10} {'unseen PSNR':>12} {'unseen SSIM':>12}"]
    fmt = lambda v, w, p: f"{v:>{w}.{p}f}" if isinstance(v, (int, float)) else f"{'-':>{w}}"  # noqa: E731
    for r in records:
        lines.append(f"{r['elapsed']:>8.0f} {r['step']:>7d} {r.get('stage', 1):>5} {fmt(r.get('seen_psnr'), 10, 2)} "
                     f"{fmt(r.get('seen_ssim'), 10, 4)} {fmt(r.get('unseen_psnr'), 12, 2)} {fmt(r.get('unseen_ssim'), 12, 4)}")
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
    for key, label, color in (("seen", "seen views", "tab:orange"), ("unseen", "unseen views", "tab:blue")):
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
