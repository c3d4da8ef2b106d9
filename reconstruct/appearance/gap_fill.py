"""Colours for gaps inside a garment layer's seen cloth (the skirt behind a photo's hand or
forearm): each gap cell's colour read from the trusted cloth on both sides of it along its row,
above and below it along its column, or both.

Why. The wrap fill gives an unseen layer Gaussian its row's colour (the row's median, its checks
carried round by their period): right for the back, which is a whole half of each row. A gap
inside the seen front is a few cells across, and the row's median there is a flat patch over the
pleats or stripes running through it (the grey-skirt photo's pleats, under her hand).

How. From each gap cell the grid is walked (``neighbours``, columns wrapping round their tube) up
to ``reach`` steps in each of the four directions to the first trusted source. Along the row, the
two colours found are interpolated linearly by distance, and so along the column; where both pairs
are found they are blended with weights inverse to each pair's span, so that the shorter span
leads: a gap under a horizontal forearm takes each column's colour from above and below it
(vertical pleats carry through), one beside a hanging arm each row's from left and right. The
grid's top or hem stands for a column's missing side (the colour from the other side carried up
to it: a gap under a hand at the waistband). A cell with neither pair gets none.

Which cells are gaps is the caller's: a whole unseen back also has cloth on both sides of each
row of a narrow tube, so only cells known to lie inside the seen front are given (Stage I's
finish gives those the arms hid, ``train/hidden_by_limbs.py``).
"""

from __future__ import annotations

import numpy as np

# the order of ``texel_neighbours`` / ``GarmentLayer.grid_neighbours``: next column, next row,
# previous column, previous row
_NEXT_COL, _NEXT_ROW, _PREV_COL, _PREV_ROW = range(4)


def _step(neighbours: np.ndarray, at: np.ndarray, live: np.ndarray, direction: int):
    """One step along ``direction`` for the walks still ``live``: (where each walk is now, still
    live, ended at the grid's edge on this step)."""
    nxt = np.where(live, neighbours[at, direction], -1)
    edge = live & (nxt < 0)
    live = live & (nxt >= 0)
    return np.where(live, nxt, at), live, edge


def _first_source(neighbours: np.ndarray, sources: np.ndarray, start: np.ndarray, direction: int,
                  reach: int) -> tuple[np.ndarray, np.ndarray]:
    """(steps, index) for each of ``start``: how many steps along ``direction`` to the first source
    (``reach + 1`` and -1 where none is within ``reach``, -2 where the grid ends first)."""
    steps = np.full(len(start), reach + 1, np.int64)
    found = np.full(len(start), -1, np.int64)
    at = start.copy()
    live = np.ones(len(start), bool)
    for k in range(1, reach + 1):
        at, live, edge = _step(neighbours, at, live, direction)
        found[edge] = -2
        hit = live & sources[at]
        steps[hit], found[hit] = k, at[hit]
        live &= ~hit
        if not live.any():
            break
    return steps, found


def _colour_from(neighbours: np.ndarray, sources: np.ndarray, colors: np.ndarray, found: np.ndarray,
                 direction: int, depth: int) -> np.ndarray:
    """(len(found),3): the per-channel median colour of the sources among the ``depth`` cells from
    each ``found`` source on along ``direction`` (the found one included): one odd cell at the gap's
    edge does not draw a streak through it. Rows whose ``found`` is negative are NaN."""
    out = np.full((len(found), 3), np.nan)
    ok = found >= 0
    if not ok.any():
        return out
    at = found[ok]
    picks = [colors[at]]
    live = np.ones(len(at), bool)
    for _ in range(depth - 1):
        at, live, _edge = _step(neighbours, at, live, direction)
        c = colors[at].copy()
        c[~(live & sources[at])] = np.nan
        picks.append(c)
    out[ok] = np.nanmedian(np.stack(picks, 0), axis=0)
    return out


def enclosed_gap_colors(neighbours: np.ndarray, sources: np.ndarray, colors: np.ndarray, todo: np.ndarray,
                        reach: int = 16, depth: int = 3) -> np.ndarray:
    """(M,3) float64: for each ``todo`` grid cell with ``sources`` within ``reach`` steps both ways
    along its row or its column, the linear interpolation between the nearest sources along each
    such pair, blended by inverse span (see the module docstring); NaN elsewhere. ``neighbours``: (M,4) grid
    neighbours in ``texel_neighbours`` order (-1 where none), ``sources``/``todo``: (M,) bool,
    ``colors``: (M,3). Each side's colour is the median of the sources among ``depth`` cells from
    the first one on."""
    neighbours = np.asarray(neighbours, np.int64)
    sources = np.asarray(sources, bool)
    todo = np.asarray(todo, bool)
    colors = np.asarray(colors, np.float64)
    m = len(sources)
    if neighbours.shape != (m, 4) or todo.shape != (m,) or colors.shape != (m, 3):
        raise ValueError(f"enclosed_gap_colors: expected neighbours (M,4), sources and todo (M,), colors (M,3) with "
                         f"M={m}; found {neighbours.shape}, {todo.shape}, {colors.shape}")
    if reach < 1:
        raise ValueError(f"enclosed_gap_colors: reach must be at least 1 grid step, found {reach}")
    if depth < 1:
        raise ValueError(f"enclosed_gap_colors: depth must be at least 1 cell, found {depth}")
    out = np.full((m, 3), np.nan)
    cells = np.flatnonzero(todo & ~sources)
    if not len(cells) or not sources.any():
        return out

    def side(direction):  # steps to the first source that way, its index, and that side's colour
        steps, found = _first_source(neighbours, sources, cells, direction, reach)
        return steps.astype(np.float64), found, _colour_from(neighbours, sources, colors, found, direction, depth)

    s_nc, i_nc, c_nc = side(_NEXT_COL)
    s_pc, i_pc, c_pc = side(_PREV_COL)
    s_nr, i_nr, c_nr = side(_NEXT_ROW)
    s_pr, i_pr, c_pr = side(_PREV_ROW)
    in_row = (i_nc >= 0) & (i_pc >= 0)
    # along the column the grid's top or hem may stand for the missing side: the colour below (or
    # above) carried up to it (a gap under a hand at the waistband)
    up, down = i_pr >= 0, i_nr >= 0
    in_col = (up & down) | (up & (i_nr == -2)) | (down & (i_pr == -2))
    c_pr, s_pr, c_nr, s_nr = (np.where(up[:, None], c_pr, c_nr), np.where(up, s_pr, s_nr),
                              np.where(down[:, None], c_nr, c_pr), np.where(down, s_nr, s_pr))

    def between(s_a, c_a, s_b, c_b, ok):  # linear between a (s_a steps one way) and b (s_b the other)
        c = (c_a * s_b[:, None] + c_b * s_a[:, None]) / (s_a + s_b)[:, None]
        return np.where(ok[:, None], c, 0.0), np.where(ok, 1.0 / (s_a + s_b), 0.0)

    row, w_row = between(s_pc, c_pc, s_nc, c_nc, in_row)
    col, w_col = between(s_pr, c_pr, s_nr, c_nr, in_col)
    some = in_row | in_col
    w = (w_row + w_col)[some]
    out[cells[some]] = (row[some] * w_row[some][:, None] + col[some] * w_col[some][:, None]) / w[:, None]
    return out
