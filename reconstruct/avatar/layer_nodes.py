"""Where the garment layer's decoder runs: every ``every``-th row and column of the layer's grid,
the Gaussians between taking the decoder's outputs bilinearly from the four nodes round them (the
body does the same with its coarser decode map, ``AvatarConfig.decode_resolution``). Each
Gaussian keeps its own colour residual, so a grid finer than its nodes carries texture at the
Gaussians' spacing for the decoder cost of the nodes.

The node rows are rows 0, every, 2 every, ... and always the last row (the hem); the node columns
are columns 0, every, 2 every, ... of each tube (its block of ``cols / tubes`` columns), wrapping
round the tube: the last node column of a tube interpolates towards its first. With ``every`` = 1
every Gaussian is its own node.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LayerNodes:
    shape: tuple[int, int]  # (node rows, node columns) of the layer's feature map
    grid_rc: np.ndarray  # (K,2) each node's row and column on the Gaussians' grid, row-major over ``shape``
    index: np.ndarray  # (M,4) the nodes round each Gaussian (row-major Gaussians)
    weights: np.ndarray  # (M,4) bilinear weights, summing to 1


def _spans(n: int, every: int, wrap: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For positions 0..n-1 on a line (``wrap``: a ring) with nodes every ``every``: node positions,
    and per position the lower and upper node (indices into them) and the fraction between."""
    nodes = list(range(0, n, every))
    if not wrap and nodes[-1] != n - 1:
        nodes.append(n - 1)
    nodes = np.asarray(nodes)
    pos = np.arange(n)
    lo = np.searchsorted(nodes, pos, side="right") - 1
    if wrap:
        hi = (lo + 1) % len(nodes)
        end = np.where(lo + 1 < len(nodes), nodes[np.minimum(lo + 1, len(nodes) - 1)], n)
    else:
        hi = np.minimum(lo + 1, len(nodes) - 1)  # the last row is its own node
        end = nodes[hi]
    span = np.maximum(end - nodes[lo], 1)
    frac = np.where(hi == lo, 0.0, (pos - nodes[lo]) / span)
    return nodes, lo, hi, frac


def layer_nodes(rows: int, cols: int, tubes: int, every: int) -> LayerNodes:
    """The decode nodes of a (``rows``, ``cols``) layer grid of ``tubes`` tubes (module docstring)."""
    if not (isinstance(every, (int, np.integer)) and every >= 1):
        raise ValueError(f"layer nodes: every must be a positive integer, found {every!r}")
    if rows < 1 or tubes < 1 or cols % tubes:
        raise ValueError(f"layer nodes: a {rows}x{cols} grid does not split into {tubes} tubes")
    per_tube = cols // tubes
    r_nodes, r_lo, r_hi, r_frac = _spans(rows, every, wrap=False)
    c_nodes, c_lo, c_hi, c_frac = _spans(per_tube, every, wrap=True)
    nr, nc = len(r_nodes), len(c_nodes)
    r, c = np.divmod(np.arange(rows * cols), cols)
    tube, local = np.divmod(c, per_tube)
    index, weights = [], []
    for rr, wr in ((r_lo[r], 1 - r_frac[r]), (r_hi[r], r_frac[r])):
        for cc, wc in ((c_lo[local], 1 - c_frac[local]), (c_hi[local], c_frac[local])):
            index.append(rr * (tubes * nc) + tube * nc + cc)
            weights.append(wr * wc)
    nr_grid, nc_grid = np.meshgrid(r_nodes, np.arange(tubes * nc), indexing="ij")
    grid_rc = np.stack([nr_grid.ravel(), (nc_grid // nc * per_tube + c_nodes[nc_grid % nc]).ravel()], 1)
    return LayerNodes((nr, tubes * nc), grid_rc.astype(np.int64), np.stack(index, 1).astype(np.int64),
                      np.stack(weights, 1))
