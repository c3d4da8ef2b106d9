"""Where a run's image error sits: the squared error of each held-out view split into the mask's
interior, a band along the silhouette's edge and the background, so that a PSNR gap between two
runs can be read as "the silhouette" (edge) or "the texture" (interior).

    OMP_NUM_THREADS=1 python benchmarks/error_split.py RUN [RUN ...] [--scale 1] [--band 2]

For every view: the mean squared error over the image (what ``eval``'s PSNR reads) equals
``interior + edge + outside``, each the sum of the squared error over that region divided by the
image's pixel count; the edge is every pixel within ``band`` pixels (Chebyshev) of the mask's
boundary, on either side; the interior is the rest of the mask, the outside the rest of the image.
``interior PSNR`` is the PSNR over the interior pixels alone (the texture, whatever the mask's
size). Per group (seen / unseen): the mean over its views (PSNRs averaged as ``eval`` does).
Prints a markdown table.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruct.train.evaluate import inner_mask, rendered_views  # noqa: E402


def regions(mask: torch.Tensor, band: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(interior, edge, outside) boolean (H,W) masks that partition the image: the edge is every
    pixel within ``band`` px of the boundary of the boolean ``mask`` on either side."""
    if band < 1:
        raise ValueError(f"band must be at least 1 pixel, found {band}")
    m = mask.float()[None, None]
    grown = F.max_pool2d(m, 2 * band + 1, stride=1, padding=band)[0, 0] > 0.5
    interior = inner_mask(mask, band)
    edge = grown & ~interior
    return interior, edge, ~grown


def error_split(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor, band: int = 2) -> dict:
    """Squared error of ``pred`` against ``gt`` ((H,W,3) in [0, 1]) split by the regions of the
    boolean (H,W) ``mask`` (module docstring)."""
    se = ((pred.double() - gt.double()) ** 2).mean(-1)
    n = se.numel()
    interior, edge, outside = regions(mask, band)
    mse = float(se.mean())
    inner = float(se[interior].mean()) if bool(interior.any()) else math.nan
    return {"foreground": float(mask.double().mean()), "mse": mse,
            "psnr": math.inf if mse == 0 else -10 * math.log10(mse),
            "interior": float(se[interior].sum()) / n, "edge": float(se[edge].sum()) / n,
            "outside": float(se[outside].sum()) / n,
            "interior_psnr": math.inf if inner == 0 else -10 * math.log10(inner)}


def summarize(rows: list[dict]) -> dict:
    return {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}


@torch.no_grad()
def split_run(run: Path, scale: int = 1, band: int = 2) -> dict[str, dict]:
    """{"seen": ..., "unseen": ...}: ``error_split`` averaged over the run's eval views, rendered as
    ``eval --scale scale`` renders them."""
    from reconstruct.run_folder import RunFolder

    trainer = RunFolder(run).resume()
    groups = {True: [], False: []}
    for v, r, gt, mask in rendered_views(trainer.state, trainer.scene, trainer.background, scale=scale):
        groups[v.seen].append(error_split(r.rgb.clamp(0, 1), gt, mask, band))
    return {("seen" if k else "unseen"): summarize(rows) for k, rows in groups.items() if rows}


def table(results: dict[str, dict[str, dict]]) -> str:
    lines = ["| run | views | foreground | PSNR | MSE ×1e4 = interior + edge + outside | interior PSNR |",
             "|---|---|---|---|---|---|"]
    for run, groups in results.items():
        for group, s in groups.items():
            lines.append(f"| {run} | {group} | {100 * s['foreground']:.2f} % | {s['psnr']:.2f} | "
                         f"{1e4 * s['mse']:.2f} = {1e4 * s['interior']:.2f} + {1e4 * s['edge']:.2f} + "
                         f"{1e4 * s['outside']:.2f} | {s['interior_psnr']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--scale", type=int, default=1, help="render at this multiple of the scene's resolution (as eval --scale)")
    p.add_argument("--band", type=int, default=2, help="pixels either side of the silhouette's edge")
    args = p.parse_args(argv)
    if args.scale < 1:
        p.error(f"--scale must be a positive integer, found {args.scale}")
    torch.set_num_threads(1)
    print(table({run.name: split_run(run, args.scale, args.band) for run in args.runs}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
