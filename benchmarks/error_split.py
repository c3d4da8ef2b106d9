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

Two more splits of the same mean squared error, each adding up to it exactly:

* ``--wavelengths A,B`` (pixels at the rendered scale): by the error's spatial wavelength
  (Parseval over the image's 2-D Fourier transform, per colour channel): ``fine`` (shorter than A:
  blurred or shifted edges), ``pattern`` (A to B: a print's stripes or checks drawn out of place)
  and ``coarse`` (B and longer, the mean included: wrong colour over whole regions, missing or
  extra cover);
* ``--heights N``: by height on the person, N equal bands from the top of the ground-truth mask to
  its bottom (rows above or below it go to the first or last band), so that runs whose person
  stands at another place in the image still compare band by band.
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


def wavelength_split(pred: torch.Tensor, gt: torch.Tensor, cuts: tuple[float, float]) -> dict:
    """The mean squared error of ``pred`` against ``gt`` ((H,W,3)) split by the error's wavelength
    in pixels: {"fine": < cuts[0], "pattern": cuts[0] to < cuts[1], "coarse": >= cuts[1] (the mean
    included)}; the three add up to the mean squared error (Parseval)."""
    lo, hi = float(cuts[0]), float(cuts[1])
    if not 0 < lo < hi:
        raise ValueError(f"wavelength cuts must be 0 < A < B pixels, found {cuts}")
    e = (pred.double() - gt.double()).permute(2, 0, 1)  # (3,H,W)
    H, W = e.shape[1:]
    power = torch.fft.fft2(e).abs().pow(2).sum(0) / (H * W) ** 2 / 3  # sums to the mean squared error
    fy, fx = torch.fft.fftfreq(H, dtype=torch.float64), torch.fft.fftfreq(W, dtype=torch.float64)
    f = torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)  # cycles per pixel
    wavelength = torch.where(f > 0, 1.0 / f.clamp_min(1e-12), torch.full_like(f, math.inf))
    return {"fine": float(power[wavelength < lo].sum()),
            "pattern": float(power[(wavelength >= lo) & (wavelength < hi)].sum()),
            "coarse": float(power[wavelength >= hi].sum())}


def height_split(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor, bands: int) -> list[float]:
    """The mean squared error of ``pred`` against ``gt`` split into ``bands`` equal bands of height
    between the top and the bottom row of the boolean ``mask`` (rows outside it counted in the end
    bands); each band's squared error summed and divided by the image's pixel count, so the bands
    add up to the mean squared error."""
    if bands < 1:
        raise ValueError(f"height bands must be at least 1, found {bands}")
    se_rows = ((pred.double() - gt.double()) ** 2).mean(-1).sum(1) / mask.numel()  # (H,)
    rows = torch.nonzero(mask.any(1)).flatten()
    H = se_rows.shape[0]
    top, bottom = (int(rows[0]), int(rows[-1]) + 1) if len(rows) else (0, H)
    band_of = ((torch.arange(H, dtype=torch.float64) + 0.5 - top) / (bottom - top) * bands).floor()
    band_of = band_of.clamp(0, bands - 1).long()
    return torch.zeros(bands, dtype=torch.float64).index_add_(0, band_of, se_rows).tolist()


def summarize(rows: list[dict]) -> dict:
    return {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}


@torch.no_grad()
def split_run(run: Path, scale: int = 1, band: int = 2, wavelengths: tuple[float, float] | None = None,
              heights: int = 0) -> dict[str, dict]:
    """{"seen": ..., "unseen": ...}: ``error_split`` averaged over the run's eval views, rendered as
    ``eval --scale scale`` renders them; with ``wavelengths`` the ``wavelength_split`` keys too, with
    ``heights`` the ``height_split`` bands as keys ``h0``, ``h1``, ..."""
    from reconstruct.run_folder import RunFolder

    trainer = RunFolder(run).resume()
    groups = {True: [], False: []}
    for v, r, gt, mask in rendered_views(trainer.state, trainer.scene, trainer.background, scale=scale):
        pred = r.rgb.clamp(0, 1)
        row = error_split(pred, gt, mask, band)
        if wavelengths is not None:
            row.update(wavelength_split(pred, gt, wavelengths))
        if heights:
            row.update({f"h{i}": x for i, x in enumerate(height_split(pred, gt, mask, heights))})
        groups[v.seen].append(row)
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


def wavelength_table(results: dict[str, dict[str, dict]], cuts: tuple[float, float]) -> str:
    a, b = (f"{c:g}" for c in cuts)
    lines = [f"| run | views | MSE ×1e4 | fine (< {a} px) | pattern ({a}-{b} px) | coarse (>= {b} px) |",
             "|---|---|---|---|---|---|"]
    for run, groups in results.items():
        for group, s in groups.items():
            lines.append(f"| {run} | {group} | {1e4 * s['mse']:.2f} | {1e4 * s['fine']:.2f} | "
                         f"{1e4 * s['pattern']:.2f} | {1e4 * s['coarse']:.2f} |")
    return "\n".join(lines)


def height_table(results: dict[str, dict[str, dict]], bands: int) -> str:
    lines = ["| run | views | " + " | ".join(f"{i}/{bands}" for i in range(bands)) + " |",
             "|---|---|" + "---|" * bands]
    for run, groups in results.items():
        for group, s in groups.items():
            lines.append(f"| {run} | {group} | " + " | ".join(f"{1e4 * s[f'h{i}']:.2f}" for i in range(bands)) + " |")
    return "\n".join(lines)


def _cuts(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two wavelengths in pixels as A,B (e.g. 8,64), found {text!r}")
    if not 0 < a < b:
        raise argparse.ArgumentTypeError(f"expected 0 < A < B, found {text!r}")
    return a, b


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--scale", type=int, default=1, help="render at this multiple of the scene's resolution (as eval --scale)")
    p.add_argument("--band", type=int, default=2, help="pixels either side of the silhouette's edge")
    p.add_argument("--wavelengths", type=_cuts, metavar="A,B",
                   help="also split the error by wavelength: fine < A px <= pattern < B px <= coarse")
    p.add_argument("--heights", type=int, default=0, metavar="N",
                   help="also split the error into N bands of height on the person (MSE ×1e4 per band, top first)")
    args = p.parse_args(argv)
    if args.scale < 1:
        p.error(f"--scale must be a positive integer, found {args.scale}")
    if args.heights < 0:
        p.error(f"--heights must be 0 (off) or more, found {args.heights}")
    torch.set_num_threads(1)
    results = {run.name: split_run(run, args.scale, args.band, args.wavelengths, args.heights) for run in args.runs}
    print(table(results))
    if args.wavelengths is not None:
        print()
        print(wavelength_table(results, args.wavelengths))
    if args.heights:
        print()
        print(f"MSE ×1e4 by height on the person, {args.heights} bands from the top of the mask to its bottom:")
        print(height_table(results, args.heights))
    return 0


if __name__ == "__main__":
    sys.exit(main())
