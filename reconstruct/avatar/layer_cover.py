"""The body under a garment layer's cloth: which body Gaussians the layer hides in canonical space,
and which layer Gaussian hides each.

Why. A coat's layer hangs 5 mm or more outside the body (``layer_clearance``), but the body's
Gaussians under it are not gone: where their learned offsets or a pose bring them through the
cloth, or where the cloth's Gaussians leave small gaps between them, they show. Unseen, they took
the wrap-around fill's colours of their own part -- the trousers' dark, or the torso's band at hip
height -- and seen from behind the coat photo's back showed a honeycomb of dark dots over the
seat, and a thigh's stripe where it came through. Painted with the colour of the cloth that hides
them, what shows through is the cloth.

Which. A body Gaussian of the parts a layer covers (``layer_clearance.COVERED_PARTS``) whose nearest
layer Gaussian in canonical space (base positions) faces it from outside (the body point is behind
the layer point along the layer's outward normal) and lies in its column's opaque run: below the
layer's top row (which may fade into the body; a body point nearest to the top row but below its
height is hidden by the row under it -- on the long-skirt photo, torso Gaussians just below the top
row kept the blouse's colour and showed through the fading top as light blotches on the skirt's
back) and no lower than the column's hem, the lowest row of the run of rows with opacity at least
``min_opacity`` that starts under the top row. The run crosses gaps of up to ``bridge_rows`` rows
(2: 2 cm at the layer's 1 cm rows, 2.8 cm at the 1.4 cm rows of before): a photo's layer has transparent specks where training
emptied a Gaussian or two, at the waist and mid-column, and a speck ended its column's run there,
so the whole body under the column took its own fill (the mirrored grey-skirt photo's thigh, skin
down the skirt's side); an open coat's front is many rows without cloth. The body point must also
be ``hem_margin`` above that hem: a hem is curved and its height differs from column to column,
and on the coat photo a strip of the shin under the back hem, whose nearest layer Gaussians were
the front's lower ones, came out in the coat's colour without the margin.
Body Gaussians above the layer's top or below its hem are not hidden.

Where the person's outline cut the layer (``cut``: Gaussians training made transparent because
they stood past the silhouette, ``AvatarModel.layer_outline_cut``), the cloth is still there: a
side of the layer built wider than the photo's skirt hangs, trained empty, a few centimetres
outside the thigh, and the thigh drew the skirt's edge. Those Gaussians count as the cloth's in the
rows where at least ``cut_row_share`` of the columns are opaque (the garment's rows: below the hem
no row is). Without it the thigh under such a side was no cloth's, took the legs' skin colour, and
showed as a skin-coloured stripe down the skirt's side from 45-135° (the grey-skirt photo
mirrored, `docs/loose_clothing.md`, "A side the outline cut").
An open coat's front is transparent too, but over the person's mask (the trousers drew it): not
cut, so the legs there keep their own colours.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .layer_clearance import covered_ids


def body_under_layer(body_positions: np.ndarray, body_parts: np.ndarray, layer_positions: np.ndarray,
                     layer_normals: np.ndarray, layer_rc: np.ndarray, grid_shape: tuple[int, int],
                     layer_opacity: np.ndarray, *, min_opacity: float = 0.5, hem_margin: float = 0.03,
                     cut: np.ndarray | None = None, cut_row_share: float = 0.5, bridge_rows: int = 2) -> np.ndarray:
    """(N,) int64 over the body's Gaussians: the index (into the layer's) of the layer Gaussian that
    hides each one, -1 for those it does not hide (see the module docstring). Canonical positions;
    ``layer_rc``: (M,2) each layer Gaussian's grid row (0 the top) and column, on a ``grid_shape``
    (rows, cols) grid; ``cut``: (M,) bool, the layer Gaussians the outline cut away (or None);
    ``bridge_rows``: the longest run of rows without cloth that a column's run crosses (0: none)."""
    body_positions = np.asarray(body_positions, np.float64)
    out = np.full(len(body_positions), -1, np.int64)
    layer_positions = np.asarray(layer_positions, np.float64)
    if len(layer_positions) == 0:
        return out
    R, C = grid_shape
    rc = np.asarray(layer_rc, np.int64)
    opaque = np.zeros((R, C), bool)
    opaque[rc[:, 0], rc[:, 1]] = np.asarray(layer_opacity, np.float64) >= min_opacity
    if cut is not None:
        cut_grid = np.zeros((R, C), bool)
        cut_grid[rc[:, 0], rc[:, 1]] = np.asarray(cut, bool)
        opaque |= cut_grid & (opaque.mean(1) >= cut_row_share)[:, None]
    z = np.zeros((R, C))
    z[rc[:, 0], rc[:, 1]] = layer_positions[:, 2]
    # each column's hem: the lowest row of the opaque run below the top row (the top row itself may
    # fade into the body), across gaps of up to ``bridge_rows``; a column with no such run hides nothing
    depth = np.zeros(C, np.int64)  # the run's last row (0: none)
    gap = np.zeros(C, np.int64)
    alive = np.ones(C, bool)
    for r in range(1, R):
        depth = np.where(alive & opaque[r], r, depth)
        gap = np.where(opaque[r], 0, gap + 1)
        alive &= gap <= bridge_rows
    hem_z = np.where(depth > 0, z[np.clip(depth, 1, R - 1), np.arange(C)], np.inf)
    ids = covered_ids(body_parts)
    _, j = cKDTree(layer_positions).query(body_positions[ids])
    j = np.asarray(j, np.int64)
    inside = ((body_positions[ids] - layer_positions[j]) * np.asarray(layer_normals, np.float64)[j]).sum(1) < 0
    row, col = rc[j, 0], rc[j, 1]
    # nearest to the top row but below its height: under the cloth, hidden by the row below
    index = np.full((R, C), -1, np.int64)
    index[rc[:, 0], rc[:, 1]] = np.arange(len(rc))
    if R > 1:
        below_top = (row == 0) & (body_positions[ids, 2] < z[0, col])
        j = np.where(below_top, index[1, col], j)
        row = np.where(below_top, 1, row)
    hidden = (inside & (row > 0) & (j >= 0) & (row <= depth[col])
              & (body_positions[ids, 2] >= hem_z[col] + hem_margin))
    out[ids[hidden]] = j[hidden]
    return out


def model_body_under_layer(model, min_opacity: float = 0.5) -> np.ndarray | None:
    """``body_under_layer`` for an ``AvatarModel``, as (N+M,) indices into all its Gaussians (-1 for
    the layer's own and the body Gaussians not hidden); None without a layer."""
    if model.layer is None or model.num_layer == 0:
        return None
    N = model.num_body
    pos = model.base_positions.detach().cpu().double().numpy()
    nrm = model.base_normals.detach().cpu().double().numpy()
    opacity = model.opacities().detach().cpu().double().numpy()
    j = body_under_layer(pos[:N], model.parts()[:N], pos[N:], nrm[N:], model.layer_rc.cpu().numpy(),
                         model.layer.grid_shape, opacity[N:], min_opacity=min_opacity,
                         cut=model.layer_outline_cut.cpu().numpy())
    out = np.full(len(pos), -1, np.int64)
    out[:N] = np.where(j >= 0, j + N, -1)
    return out
