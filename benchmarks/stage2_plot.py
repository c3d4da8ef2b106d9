"""Error against run time across both stages, with Stage II's λ_SDS (Eq. 14) on a second axis,
from a run's metrics.jsonl.

    python benchmarks/stage2_plot.py RUN [--out RUN/stage2_error_vs_time.png]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    evals, trains = [], []
    for line in (args.run / "metrics.jsonl").read_text().splitlines():
        rec = json.loads(line)
        (evals if rec.get("kind") == "eval" else trains if rec.get("kind") == "train" else []).append(rec)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    t = [r["elapsed"] / 60 for r in evals]
    for key, style in (("seen_psnr", "-o"), ("unseen_psnr", "-s")):
        ax.plot(t, [r[key] for r in evals], style, label=key.replace("_", " "))
    s2 = [r for r in evals if r.get("stage") == 2]
    if s2:
        start = min(r["elapsed"] for r in trains if r.get("stage") == 2) / 60 if any(
            r.get("stage") == 2 for r in trains) else s2[0]["elapsed"] / 60
        ax.axvline(start, ls="--", c="k", lw=0.8)
        ax.text(start, ax.get_ylim()[0], " Stage II", va="bottom")
    ax.set_xlabel("training time (min)")
    ax.set_ylabel("PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left")
    lam = [(r["elapsed"] / 60, r["sds_weight"]) for r in trains if r.get("stage") == 2 and "sds_weight" in r]
    if lam:
        ax2 = ax.twinx()
        ax2.step([x for x, _ in lam], [y for _, y in lam], "r-", where="post", lw=1, label="λ_SDS")
        ax2.set_ylabel("λ_SDS", color="r")
        ax2.set_ylim(0, max(y for _, y in lam) * 1.2)
    ax.set_title(f"{args.run.name}: error against run time, both stages")
    out = args.out or args.run / "stage2_error_vs_time.png"
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
