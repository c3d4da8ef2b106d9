"""Stage I at a laptop's budgets: seen / unseen PSNR, holes and alpha IoU at x2, front leak, per
seed and budget, and the error-against-time plot (issue 13's table).

A *minutes* budget depends on what else the machine runs. To measure it on a shared machine the
budget is turned into steps at the rate a quiet run of this machine reaches (``--rate``: steps per
second of a ``--minutes`` run with the machine to itself, on ``--threads``), and each run gets
``--iters`` = rate x 60 x minutes. The learning-rate schedule is laid over whichever budget is
given, so such a run takes the same steps at the same learning rates as the quiet minutes run
would; only its wall time differs.

    python benchmarks/stage1_budgets.py run --out DIR --seeds 0 1 2 --minutes 10 20 --rate 4.62 [--parallel 2]
    python benchmarks/stage1_budgets.py report DIR/r10_s0 DIR/r20_s0 ... --rate 4.62 [--plot PNG]

``report`` reads each run folder (and ``RUN.eval2.json``, ``eval --json --scale 2`` of it, for the
holes and alpha IoU at x2). A run recorded before Stage I filled its unseen side (``fill_unseen``)
is shown both as trained and with the fill applied as the trainer now does at the end of Stage I
(the fill happens after the last step and changes colours only, so it is the same avatar the
current code would end with).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


def _run_one(out: Path, seed: int, minutes: float, rate: float, threads: int, eval_every: float) -> Path:
    run = out / f"r{minutes:g}_s{seed}"
    iters = int(round(rate * 60 * minutes))
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    cli = [sys.executable, "-m", "app.cli"]
    with open(f"{run}.log", "w") as log:
        subprocess.run(cli + ["train", "--scene", f"synthetic:seed={seed}", "--out", str(run), "--stage", "1",
                              "--iters", str(iters), "--threads", str(threads), "--eval-every", str(eval_every),
                              "--quiet"], check=True, stdout=log, stderr=subprocess.STDOUT, env=env)
        with open(f"{run}.eval2.json", "w") as fh:
            subprocess.run(cli + ["eval", str(run), "--json", "--scale", "2"], check=True, stdout=fh, stderr=log,
                           env=env)
    return run


def _evals(run: Path) -> list[dict]:
    from reconstruct.train.metrics_log import MetricsLog

    return MetricsLog(run / "metrics.jsonl").read("eval")


def _last_eval(run: Path) -> dict:
    rows = _evals(run)
    if not rows:
        raise SystemExit(f"{run / 'metrics.jsonl'}: no evaluation records")
    return rows[-1]


def _filled_eval(run: Path) -> tuple[dict, bool]:
    """The final evaluation with the unseen fill (applied here for runs recorded before it)."""
    import torch

    from reconstruct.run_folder import RunFolder
    from reconstruct.train.unseen_fill import fill_unseen_colors

    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    trainer = RunFolder(run).resume()
    if trainer.config.fill_unseen:
        return _last_eval(run), False
    fill_unseen_colors(trainer.state, keep_ring=type(trainer.config)().fill_unseen_ring)
    _, summary = trainer.evaluate()
    return summary, True


def report(runs: list[Path], rate: float) -> tuple[str, list[dict]]:
    rows = []
    for run in runs:
        raw = _last_eval(run)
        filled, applied = _filled_eval(run)
        x2 = {}
        e2 = Path(f"{run}.eval2.json")
        if e2.exists():
            x2 = json.loads(e2.read_text())
            x2 = x2.get("summary", x2)
        info = json.loads((run / "run.json").read_text())
        rows.append({"run": run.name, "scene": info.get("scene"), "steps": raw["step"],
                     "minutes": raw["step"] / rate / 60, "raw": raw, "final": filled, "applied": applied, "x2": x2})
    head = ("| run | steps | quiet-equivalent min | seen PSNR | unseen PSNR (as trained → filled) | seen SSIM "
            "| unseen SSIM | holes ×2 seen / unseen | alpha IoU ×2 seen / unseen | front leak |")
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        a, f, x = r["raw"], r["final"], r["x2"]
        holes = (f"{100 * x['seen_hole_fraction']:.2f} % / {100 * x['unseen_hole_fraction']:.2f} %"
                 if "seen_hole_fraction" in x else "–")
        iou = f"{x['seen_alpha_iou']:.3f} / {x['unseen_alpha_iou']:.3f}" if "seen_alpha_iou" in x else "–"
        unseen = (f"{a['unseen_psnr']:.2f} → {f['unseen_psnr']:.2f}" if r["applied"] else f"{f['unseen_psnr']:.2f}")
        leak = f.get("front_leak")
        lines.append(f"| {r['run']} | {r['steps']} | {r['minutes']:.1f} | {f['seen_psnr']:.2f} | {unseen} "
                     f"| {f['seen_ssim']:.4f} | {f['unseen_ssim']:.4f} | {holes} | {iou} "
                     f"| {'–' if leak is None else f'{leak:.3f}'} |")
    return "\n".join(lines), rows


def plot(runs: list[Path], rows: list[dict], rate: float, out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (run, row) in enumerate(zip(runs, rows)):
        evals = _evals(run)
        t = [e["step"] / rate / 60 for e in evals]
        c = colors[i % len(colors)]
        for ax, key in zip(axes, ("seen_psnr", "unseen_psnr")):
            ax.plot(t, [e[key] for e in evals], "o-", ms=3, color=c, label=row["run"])
            if row["applied"] or key == "unseen_psnr":
                ax.plot([t[-1]], [row["final"][key]], "*", ms=11, color=c)
    for ax, name in zip(axes, ("seen views", "unseen views")):
        ax.set_xlabel("training time of a quiet 2-thread run (min)")
        ax.set_ylabel(f"PSNR, {name} (dB)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[1].set_title("★ end of Stage I, unseen side filled", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    r.add_argument("--minutes", type=float, nargs="+", default=[3, 10, 20])
    r.add_argument("--rate", type=float, required=True, help="steps/s of a quiet --minutes run on this machine")
    r.add_argument("--threads", type=int, default=1)
    r.add_argument("--parallel", type=int, default=1)
    r.add_argument("--eval-every", type=float, default=150.0)
    p = sub.add_parser("report")
    p.add_argument("runs", type=Path, nargs="+")
    p.add_argument("--rate", type=float, required=True)
    p.add_argument("--plot", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.cmd == "run":
        args.out.mkdir(parents=True, exist_ok=True)
        jobs = sorted(((s, m) for m in args.minutes for s in args.seeds), key=lambda j: -j[1])
        with ThreadPoolExecutor(args.parallel) as pool:
            runs = list(pool.map(lambda j: _run_one(args.out, j[0], j[1], args.rate, args.threads, args.eval_every),
                                 jobs))
        args = ap.parse_args(["report", *map(str, runs), "--rate", str(args.rate)])
    text, rows = report(args.runs, args.rate)
    print(text)
    if args.plot:
        print(f"wrote {plot(args.runs, rows, args.rate, args.plot)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
