"""Stage II results table from run folders: Stage I (the last Stage I evaluation) against the end of
Stage II, seen and unseen views, PSNR and SSIM, per run (e.g. the ablations of the paper's Table 4
or several seeds), with the front-leak ("tattoo") score where the scene has one.

Stage I ends with its unseen fill (``fill_unseen``), which is evaluated at the last Stage I step.
Where the run filled and evaluated earlier, the last evaluation before that is reported as
"Stage I as trained": the unseen side as the paper's Stage I leaves it (evaluate often, e.g.
``--eval-every 300``, so that it is close to the end of Stage I).

    python benchmarks/stage2_report.py runs/exp/s0_full runs/exp/s0_no_canonical_sds ... [--summary]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _evals(run: Path) -> list[dict]:
    rows = []
    with open(run / "metrics.jsonl") as fh:
        for line in fh:
            rec = json.loads(line)
            if rec.get("kind") == "eval":
                rows.append(rec)
    return rows


def summarize(run: Path) -> dict:
    evals = _evals(run)
    s1 = [r for r in evals if r.get("stage", 1) == 1]
    s2 = [r for r in evals if r.get("stage") == 2]
    if not s1 or not s2:
        raise ValueError(f"{run}: needs Stage I and Stage II evaluations in metrics.jsonl")
    a, b = s1[-1], s2[-1]
    info = json.loads((run / "run.json").read_text())
    filled = bool(info.get("config", {}).get("fill_unseen", False))
    earlier = [r for r in s1 if r["step"] < a["step"]]
    return {"run": run.name, "scene": info.get("scene"), "s1": a, "s2": b,
            "s1_trained": earlier[-1] if filled and earlier else None,
            "stage2_steps": b["step"] - a["step"], "stage2_seconds": b["elapsed"] - a["elapsed"]}


def _leak(rec: dict) -> str:
    v = rec.get("front_leak")
    return "–" if v is None else f"{v:.3f}"


def _trained(r: dict) -> str:
    t, b = r.get("s1_trained"), r["s2"]
    if t is None:
        return "–"
    return f"{t['unseen_psnr']:.2f} @{t['step']} ({b['unseen_psnr'] - t['unseen_psnr']:+.2f})"


def table(rows: list[dict]) -> str:
    head = ("| run | scene | Stage II steps | seen PSNR I → II | seen SSIM I → II | unseen PSNR I → II (Δ) "
            "| unseen SSIM I → II | front_leak I → II | unseen PSNR, Stage I as trained (II − it) |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        a, b = r["s1"], r["s2"]
        lines.append(f"| {r['run']} | {r['scene']} | {r['stage2_steps']} | {a['seen_psnr']:.2f} → {b['seen_psnr']:.2f} "
                     f"| {a['seen_ssim']:.4f} → {b['seen_ssim']:.4f} "
                     f"| {a['unseen_psnr']:.2f} → {b['unseen_psnr']:.2f} ({b['unseen_psnr'] - a['unseen_psnr']:+.2f}) "
                     f"| {a['unseen_ssim']:.4f} → {b['unseen_ssim']:.4f} | {_leak(a)} → {_leak(b)} | {_trained(r)} |")
    return "\n".join(lines)


def deltas(r: dict) -> dict:
    a, b = r["s1"], r["s2"]
    la, lb = a.get("front_leak"), b.get("front_leak")
    return {"unseen_psnr": b["unseen_psnr"] - a["unseen_psnr"], "unseen_ssim": b["unseen_ssim"] - a["unseen_ssim"],
            "seen_psnr": b["seen_psnr"] - a["seen_psnr"],
            "leak_ratio": (lb / la if la else (0.0 if not lb else float("inf"))) if la is not None and lb is not None
            else None}


def summary(rows: list[dict]) -> str:
    """Mean and worst run of the changes Stage II made (unseen PSNR / SSIM, seen PSNR, front_leak
    after / before)."""
    d = [deltas(r) for r in rows]
    if not d:
        return ""
    mean = lambda k: sum(x[k] for x in d) / len(d)  # noqa: E731
    worst_u = min(d, key=lambda x: x["unseen_psnr"])
    leaks = [x["leak_ratio"] for x in d if x["leak_ratio"] is not None]
    out = [f"mean over {len(d)} runs: unseen PSNR {mean('unseen_psnr'):+.2f} dB, unseen SSIM {mean('unseen_ssim'):+.4f}, "
           f"seen PSNR {mean('seen_psnr'):+.2f} dB",
           f"worst: unseen PSNR {worst_u['unseen_psnr']:+.2f} dB ({rows[d.index(worst_u)]['run']}), "
           f"unseen SSIM {min(x['unseen_ssim'] for x in d):+.4f}, seen PSNR {min(x['seen_psnr'] for x in d):+.2f} dB"
           + (f", front_leak II/I at most {max(leaks):.2f}" if leaks else "")]
    trained = [r["s2"]["unseen_psnr"] - r["s1_trained"]["unseen_psnr"] for r in rows if r.get("s1_trained")]
    if trained:
        out.append(f"against Stage I as trained (before its fill), {len(trained)} runs: unseen PSNR mean "
                   f"{sum(trained) / len(trained):+.2f} dB, worst {min(trained):+.2f} dB")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--summary", action="store_true", help="mean and worst run")
    args = ap.parse_args(argv)
    rows = []
    for run in args.runs:
        try:
            rows.append(summarize(run))
        except (OSError, ValueError) as exc:
            print(f"skipped {run}: {exc}", file=sys.stderr)
    print(table(rows))
    if args.summary:
        print()
        print(summary(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
