"""Where round the person a run loses against a reference run: PSNR and rendered-alpha IoU per
evaluation azimuth (the mean over the evaluation frames at that azimuth), read from the JSON that
``eval --json`` writes, and each run's difference from the first.

    wonderhuman-studio eval REF --json --scale 2 > REF.json
    wonderhuman-studio eval RUN --json --scale 2 > RUN.json
    python benchmarks/azimuth_gap.py REF.json RUN.json [RUN2.json ...]

The table has one row per azimuth (``seen`` marks the azimuths the training video covered) and,
below it, the mean over the unseen azimuths grouped as the sides (within 60 degrees of 90 or 270)
and the back (within 30 degrees of 180). A garment whose loss sits at the sides and not at the back
is drawn wrong in profile (an opening, the outline), not filled wrong behind.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path


def per_azimuth(report: dict, source: str = "report") -> dict[int, dict]:
    """{azimuth in whole degrees: {"psnr", "alpha_iou" (None when no view has it), "seen", "views"}}
    from an ``eval --json`` report's ``views``."""
    views = report.get("views")
    if not isinstance(views, list) or not views:
        raise ValueError(f"{source}: expected the 'views' list that `eval --json` writes, found "
                         f"{type(views).__name__ if views is not None else 'no views key'}")
    acc: dict[int, dict] = defaultdict(lambda: {"psnr": [], "alpha_iou": [], "seen": set()})
    for i, v in enumerate(views):
        for key in ("azimuth_deg", "psnr", "seen"):
            if key not in v:
                raise ValueError(f"{source}: view {i} has no {key!r}")
        a = int(round(float(v["azimuth_deg"]))) % 360
        acc[a]["psnr"].append(float(v["psnr"]))
        if v.get("alpha_iou") is not None:
            acc[a]["alpha_iou"].append(float(v["alpha_iou"]))
        acc[a]["seen"].add(bool(v["seen"]))
    out = {}
    for a in sorted(acc):
        d = acc[a]
        out[a] = {"psnr": sum(d["psnr"]) / len(d["psnr"]),
                  "alpha_iou": sum(d["alpha_iou"]) / len(d["alpha_iou"]) if d["alpha_iou"] else None,
                  "seen": all(d["seen"]), "views": len(d["psnr"])}
    return out


def group_of(azimuth: int) -> str | None:
    """"back" within 30 degrees of 180, "sides" within 60 degrees of 90 or 270, else None."""
    a = azimuth % 360
    if abs(a - 180) <= 30:
        return "back"
    if min(abs(a - 90), abs(a - 270)) <= 60:
        return "sides"
    return None


def group_means(table: dict[int, dict], key: str = "psnr") -> dict[str, float]:
    """Mean of ``key`` over the unseen azimuths of each group (sides, back, all unseen)."""
    groups: dict[str, list[float]] = defaultdict(list)
    for a, row in table.items():
        if row["seen"] or row[key] is None:
            continue
        groups["unseen"].append(row[key])
        g = group_of(a)
        if g is not None:
            groups[g].append(row[key])
    return {g: sum(v) / len(v) for g, v in groups.items()}


def format_table(names: list[str], tables: list[dict[int, dict]]) -> str:
    ref = tables[0]
    azimuths = sorted(set().union(*[t.keys() for t in tables]))
    head = "| azimuth | seen | " + " | ".join(f"{n} PSNR / IoU" for n in names)
    head += "".join(f" | {n} − {names[0]}" for n in names[1:]) + " |"
    lines = [head, "|" + "---|" * (2 + len(names) + len(names) - 1)]
    for a in azimuths:
        cells = [str(a), "yes" if ref.get(a, {}).get("seen") else ""]
        for t in tables:
            r = t.get(a)
            iou = "–" if r is None or r["alpha_iou"] is None else f"{r['alpha_iou']:.3f}"
            cells.append("–" if r is None else f"{r['psnr']:.2f} / {iou}")
        for t in tables[1:]:
            cells.append(f"{t[a]['psnr'] - ref[a]['psnr']:+.2f}" if a in t and a in ref else "–")
        lines.append("| " + " | ".join(cells) + " |")
    means = [group_means(t) for t in tables]
    for g in ("sides", "back", "unseen"):
        cells = [f"mean, unseen {g}" if g != "unseen" else "mean, all unseen", ""]
        cells += [f"{m[g]:.2f}" if g in m else "–" for m in means]
        cells += [f"{m[g] - means[0][g]:+.2f}" if g in m and g in means[0] else "–" for m in means[1:]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("reports", nargs="+", type=Path, help="eval --json outputs; the first is the reference")
    args = p.parse_args(argv)
    tables, names = [], []
    for path in args.reports:
        try:
            report = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            print(f"azimuth_gap: cannot read {path} as JSON: {e}", file=sys.stderr)
            return 2
        try:
            tables.append(per_azimuth(report, str(path)))
        except ValueError as e:
            print(f"azimuth_gap: {e}", file=sys.stderr)
            return 2
        names.append(path.stem)
    print(format_table(names, tables))
    return 0


if __name__ == "__main__":
    sys.exit(main())
