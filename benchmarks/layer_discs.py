"""Long and thin discs on a run's garment layer: the needles and spikes a hem or a stretched side
draws past the cloth when the layer's grid steps jump (docs/loose_clothing.md, "A floor-length hem
past the body's end").

    python benchmarks/layer_discs.py RUN [RUN ...]

Per run, over the layer's Gaussians whose learned opacity is above ``--opacity`` (0.3): how many
there are, how many discs are longer than 3 and 5 cm (the longer in-plane axis of the decoded
canonical scale), how many are more than 4 times longer than wide, the median length over the
hem's last 6 rows, and the largest 3D step down a column over those rows (a ring that runs off
sideways between two rows shows here first).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HEM_ROWS = 6


@dataclass(frozen=True)
class DiscStats:
    layer: int  # the layer's Gaussians
    opaque: int  # of them with opacity above the threshold (the rest of the counts are over these)
    over_3cm: int
    over_5cm: int
    thin: int  # longer than 4 times their width
    hem_median_cm: float  # median length over the last HEM_ROWS rows (all, opaque or not)
    hem_step_cm: float  # the largest 3D step down a column over the last HEM_ROWS rows


def disc_stats(scales: np.ndarray, opacity: np.ndarray, positions: np.ndarray, grid_shape: tuple[int, int],
               threshold: float = 0.3) -> DiscStats:
    """``scales`` (N,3) the layer's canonical scales (two in-plane axes, then the thickness),
    ``opacity`` (N,), ``positions`` (N,3) its built points on the (rows, cols) grid, row-major."""
    R, C = grid_shape
    scales, opacity, positions = (np.asarray(a, np.float64) for a in (scales, opacity, positions))
    n = R * C
    if scales.shape != (n, 3) or opacity.shape != (n,) or positions.shape != (n, 3):
        raise ValueError(f"expected {n} Gaussians on a {R} x {C} grid (scales and positions (N,3), opacity (N,)), "
                         f"found scales {scales.shape}, opacity {opacity.shape}, positions {positions.shape}")
    major, minor = scales[:, :2].max(1), np.maximum(scales[:, :2].min(1), 1e-12)
    keep = opacity > threshold
    hem = slice(max(0, R - HEM_ROWS), R)
    P = positions.reshape(R, C, 3)
    steps = np.linalg.norm(np.diff(P[max(0, R - HEM_ROWS - 1):], axis=0), axis=-1)
    return DiscStats(layer=n, opaque=int(keep.sum()), over_3cm=int((keep & (major > 0.03)).sum()),
                     over_5cm=int((keep & (major > 0.05)).sum()), thin=int((keep & (major > 4 * minor)).sum()),
                     hem_median_cm=100 * float(np.median(major.reshape(R, C)[hem])),
                     hem_step_cm=100 * float(steps.max()) if steps.size else 0.0)


def run_stats(run, threshold: float = 0.3) -> DiscStats | None:
    """``disc_stats`` of run folder ``run``'s checkpoint (None when its avatar has no layer)."""
    import torch

    from reconstruct.run_folder import RunFolder

    state = RunFolder(run).resume().state
    model = state.model
    if model.layer is None:
        return None
    nb = model.num_body
    with torch.no_grad():
        canon = state.canonical(0)
        opacity = model.opacities()[nb:]
    return disc_stats(canon.scales[nb:].numpy(), opacity.numpy(), model.layer.positions.numpy(),
                      tuple(model.layer.grid_shape), threshold)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--opacity", type=float, default=0.3, help="count only layer Gaussians above this opacity")
    args = ap.parse_args(argv)
    print(f"| run | layer | opacity > {args.opacity:g} | > 3 cm | > 5 cm | > 4:1 | hem median | hem's largest step |")
    print("|---|---|---|---|---|---|---|---|")
    for run in args.runs:
        s = run_stats(run, args.opacity)
        if s is None:
            print(f"| {run} | no garment layer | | | | | | |")
            continue
        print(f"| {run} | {s.layer} | {s.opaque} | {s.over_3cm} | {s.over_5cm} | {s.thin} | "
              f"{s.hem_median_cm:.2f} cm | {s.hem_step_cm:.2f} cm |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
