"""The garment layer's front and back drawn as deep as its sides (``Stage1Config.layer_depth_match``).

A splat is drawn a little past its centre: on the benchmark's coats the rendered silhouette lies
about 4 mm outside the layer's Gaussians. Training on front views pulls the layer's sides in by
that much (their decoded offsets along the layer's normals: the sides lie 4.2 mm inside the
coat's surface on coat seed 0, frame 0), so the front view's outline is right. The front and the
back are never at a training view's silhouette and keep the depth the layer was built with (1.6 mm
outside the coat, median), so from the side the avatar stood about 6 mm too deep at the front and
at the back: cloth drawn past the outline at every unseen side view.

``depth_pulls`` reads, row by row of the layer's grid, how far the sides were pulled in more than
the front and back were (the median normal offset of the opaque Gaussians facing sideways minus
that of those facing the front or the back); ``match_layer_depth`` moves each Gaussian's built
position inward in depth by its row's pull times the depth component of its normal (the whole pull
at the front and the back, nothing at the sides). A video that turned, whose front and back were
seen in profile and pulled in by training, gets no pull. Run once, at the end of Stage I.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import median_filter

FACING = 0.7  # |normal component| above which a Gaussian faces sideways (x) or front/back (y)
MIN_PER_ROW = 4  # opaque Gaussians of each kind a row needs for its own pull


@dataclass
class DepthMatch:
    """What ``match_layer_depth`` did: the pull per row (metres, (R,)) and how far each layer
    Gaussian moved in depth by this call (metres, (M,); zeros when an earlier call made the move)."""

    pulls: np.ndarray
    shift: np.ndarray

    def describe(self) -> str:
        moved = self.shift > 1e-4
        if not moved.any():
            return "garment layer: front and back already as deep as the sides"
        return (f"garment layer: front and back moved in by the sides' pull, median {1e3 * np.median(self.pulls):.1f} mm "
                f"over rows (up to {1e3 * self.pulls.max():.1f}), {int(moved.sum())} Gaussians moved")


def depth_pulls(normal_offsets: np.ndarray, normals: np.ndarray, rows: np.ndarray, opaque: np.ndarray, n_rows: int,
                *, smooth_rows: int = 5, max_pull: float = 0.01) -> np.ndarray:
    """(n_rows,) metres: per row, max(0, median normal offset of the opaque front/back-facing
    Gaussians - that of the sideways-facing ones), a running median over ``smooth_rows`` rows,
    clipped to ``max_pull``. Rows with fewer than ``MIN_PER_ROW`` of either kind take the nearest
    rows' values; no row with both: zeros.

    normal_offsets (M,) the decoded offsets along the built normals; normals (M,3) the built
    (canonical) normals, +Y the body's back; rows (M,) each Gaussian's grid row; opaque (M,) bool."""
    normal_offsets, normals = np.asarray(normal_offsets, np.float64), np.asarray(normals, np.float64)
    rows, opaque = np.asarray(rows), np.asarray(opaque, bool)
    side = opaque & (np.abs(normals[:, 0]) > FACING)
    depth = opaque & (np.abs(normals[:, 1]) > FACING)
    raw = np.full(n_rows, np.nan)
    for r in range(n_rows):
        s, d = side & (rows == r), depth & (rows == r)
        if s.sum() >= MIN_PER_ROW and d.sum() >= MIN_PER_ROW:
            raw[r] = np.median(normal_offsets[d]) - np.median(normal_offsets[s])
    ok = np.isfinite(raw)
    if not ok.any():
        return np.zeros(n_rows)
    if not ok.all():
        raw = np.interp(np.arange(n_rows), np.flatnonzero(ok), raw[ok])  # ends take the nearest row's
    if smooth_rows > 1:
        raw = median_filter(raw, size=smooth_rows, mode="nearest")
    return np.clip(raw, 0.0, max_pull)


@torch.no_grad()
def match_layer_depth(model, *, max_pull: float = 0.01) -> DepthMatch | None:
    """Move the garment layer's built positions (``model.base_positions`` and ``model.layer.positions``)
    inward in depth by their row's ``depth_pulls`` times the depth component of their built normal.
    The move is recorded (``GarmentLayer.depth_shift``); the pulls are read from the decoded offsets,
    which the move does not change, so a second call (a finish run again on a finished checkpoint)
    finds the same target and moves nothing more. None without a layer."""
    if model.layer is None or model.num_layer == 0:
        return None
    nb = model.num_body
    R, C = model.layer.grid_shape
    base = model.base_positions[nb:]
    normals = model.base_normals[nb:]
    offsets = model.canonical(None).means[nb:] - base
    normal_offsets = (offsets * normals).sum(1).cpu().numpy()
    rows = np.arange(model.num_layer) // int(C)
    opaque = (model.opacities()[nb:] > 0.5).cpu().numpy()
    pulls = depth_pulls(normal_offsets, normals.cpu().numpy(), rows, opaque, int(R), max_pull=max_pull)
    n_y = normals[:, 1].cpu().numpy().astype(np.float64)
    target = torch.as_tensor(-pulls[rows] * n_y, dtype=base.dtype, device=base.device)  # the front (-Y) moves back
    done = model.layer.depth_shift
    delta = torch.zeros_like(base)
    delta[:, 1] = target - (0 if done is None else done.to(base.device, base.dtype))
    model.move_layer(delta)
    model.layer.depth_shift = target.detach().cpu().float()
    shift = delta[:, 1].abs().cpu().numpy().astype(np.float64)
    return DepthMatch(pulls, shift)
