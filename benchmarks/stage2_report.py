"""Stage II results table from run folders: Stage I (the last Stage I evaluation) against the end of
Stage II, seen and unseen views, PSNR and SSIM, per run (e.g. the ablations of the paper's Table 4
or several seeds).

    python benchmarks/stage2_report.py runs/exp/s0_full runs/exp/s0_no_canonical_sds ...
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
    return {"run": run.name, "scene": info.get("scene"), "s1": a, "s2": b,
            "stage2_steps": b["step"] - a["step"], "stage2_seconds": b["elapsed"] - a["elapsed"]}


def table(rows: list[dict]) -> str:
    head = ("| run | scene | Stage II steps | seen PSNR I → II | seen SSIM I → II | unseen PSNR I → II (Δ) "
            "| unseen SSIM I → II |")
    lines = [head, "|" + "---|" * 7]
    for r in rows:
        a, b = r["s1"], r["s2"]
        lines.append(f"| {r['run']} | {r['scene']} | {r['stage2_steps']} | {a['seen_psnr']:.2f} → {b['seen_psnr']:.2f} "
                     f"| {a['seen_ssim']:.4f} → {b['seen_ssim']:.4f} "
                     f"| {a['unseen_psnr']:.2f} → {b['unseen_psnr']:.2f} ({b['unseen_psnr'] - a['unseen_psnr']:+.2f}) "
                     f"| {a['unseen_ssim']:.4f} → {b['unseen_ssim']:.4f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    args = ap.parse_args(argv)
    rows = []
    for run in args.runs:
        try:
            rows.append(summarize(run))
        except (OSError, ValueError) as exc:
            print(f"skipped {run}: {exc}", file=sys.stderr)
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
