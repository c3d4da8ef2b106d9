"""Colours for gaps inside a garment layer's seen cloth (``appearance/gap_fill.py``), against a
float64 reference written cell by cell, on plain and wrapping grids."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruct.appearance.gap_fill import enclosed_gap_colors
from reconstruct.body.uv_map import texel_neighbours


def _grid(rows: int, cols: int, wrap: bool = False) -> np.ndarray:
    """(rows*cols, 4) neighbours in ``texel_neighbours`` order of a row-major grid; columns wrap
    round with ``wrap`` (a garment layer's tube)."""
    if not wrap:
        rc = np.stack(np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"), -1).reshape(-1, 2)
        square = texel_neighbours(rc, max(rows, cols))
        return square
    idx = np.arange(rows * cols).reshape(rows, cols)
    out = np.full((rows, cols, 4), -1)
    out[..., 0] = np.roll(idx, -1, axis=1)
    out[:-1, :, 1] = idx[1:]
    out[..., 2] = np.roll(idx, 1, axis=1)
    out[1:, :, 3] = idx[:-1]
    return out.reshape(-1, 4)


def _reference(rows, cols, sources, colors, todo, reach, depth, wrap=False):
    """Cell by cell: walk each way to the first source (the grid's top or hem standing for a
    column's missing side), the median of ``depth`` cells from it, linear along each complete
    pair, pairs blended by inverse span."""
    S = sources.reshape(rows, cols)
    C = colors.reshape(rows, cols, 3)
    out = np.full((rows * cols, 3), np.nan)

    def walk(r, c, dr, dc):
        for k in range(1, reach + 1):
            rr, cc = r + dr * k, c + dc * k
            if wrap:
                cc %= cols
            if not (0 <= rr < rows and 0 <= cc < cols):
                return "edge", None
            if S[rr, cc]:
                picks = []
                for j in range(depth):
                    r2, c2 = rr + dr * j, cc + dc * j
                    if wrap:
                        c2 %= cols
                    if not (0 <= r2 < rows and 0 <= c2 < cols):
                        break
                    if S[r2, c2] or j == 0:
                        picks.append(C[r2, c2])
                return k, np.median(np.array(picks), 0)
        return None, None

    for i in np.flatnonzero(todo & ~sources):
        r, c = divmod(i, cols)
        left, right, up, down = walk(r, c, 0, -1), walk(r, c, 0, 1), walk(r, c, -1, 0), walk(r, c, 1, 0)
        parts, weights = [], []
        if isinstance(left[0], int) and isinstance(right[0], int):
            parts.append((left[1] * right[0] + right[1] * left[0]) / (left[0] + right[0]))
            weights.append(1 / (left[0] + right[0]))
        if isinstance(up[0], int) or isinstance(down[0], int):
            if up[0] == "edge":
                up = down
            if down[0] == "edge":
                down = up
            if isinstance(up[0], int) and isinstance(down[0], int):
                parts.append((up[1] * down[0] + down[1] * up[0]) / (up[0] + down[0]))
                weights.append(1 / (up[0] + down[0]))
        if parts:
            out[i] = np.average(np.array(parts), axis=0, weights=weights)
    return out


def _stripes(rows, cols, rng):
    """Vertical stripes (a pleated skirt): each column its own grey, plus a little noise."""
    col = rng.uniform(0.2, 0.8, cols)
    img = np.repeat(col[None, :, None], rows, 0).repeat(3, 2) + rng.normal(0, 0.01, (rows, cols, 3))
    return img.reshape(-1, 3)


@pytest.mark.parametrize("wrap", [False, True])
def test_a_hole_in_stripes_matches_the_reference(wrap):
    rng = np.random.default_rng(0)
    rows, cols = 14, 20
    colors = _stripes(rows, cols, rng)
    hole = np.zeros((rows, cols), bool)
    hole[5:8, 4:13] = True  # a forearm lying across the cloth: wide and low
    hole[0:4, 15:18] = True  # a hand at the waistband: the grid's top above it
    sources = ~hole.reshape(-1)
    todo = hole.reshape(-1)
    got = enclosed_gap_colors(_grid(rows, cols, wrap), sources, colors, todo, reach=16, depth=3)
    ref = _reference(rows, cols, sources, colors, todo, 16, 3, wrap)
    assert np.isfinite(got[todo]).all()
    np.testing.assert_allclose(got, ref, atol=1e-12)
    assert np.isnan(got[~todo]).all()
    # the low, wide gap is led by its columns: the stripes carry through, nearer them than a flat
    # fill with the cloth's mean is (the row's share, 0.3 of the weight here, blurs them)
    arm = np.zeros((rows, cols), bool)
    arm[5:8, 4:13] = True
    a = arm.reshape(-1)
    stripe = colors.reshape(rows, cols, 3)[0][None].repeat(rows, 0).reshape(-1, 3)
    flat = np.abs(colors[~hole.reshape(-1)].mean(0) - stripe[a]).mean()
    assert np.abs(got[a] - stripe[a]).mean() < 0.6 * flat


def test_no_pair_within_reach_is_nan_and_wrapping_closes_a_row():
    """A hole 6 cells wide and tall in a grid 8 wide: with a reach of 2 no cell has cloth both
    ways along its row or its column. Round a tube the row's ends meet."""
    rows, cols = 12, 8
    colors = np.full((rows * cols, 3), 0.5)
    hole = np.zeros((rows, cols), bool)
    hole[3:9, 1:7] = True
    sources, todo = ~hole.reshape(-1), hole.reshape(-1)
    plain = enclosed_gap_colors(_grid(rows, cols), sources, colors, todo, reach=2)
    assert np.isnan(plain).all()
    # the first column, 9 cells tall: on a plain grid its row has no cloth to the left and its
    # column none within 2 of its middle; round a tube the last column is its left neighbour
    colors = np.full((rows, cols, 3), 0.5)
    colors[:, -1], colors[:, 1] = 0.2, 0.6
    colors = colors.reshape(-1, 3)
    hole = np.zeros((rows, cols), bool)
    hole[2:11, 0] = True
    sources, todo = ~hole.reshape(-1), hole.reshape(-1)
    middle = np.zeros((rows, cols), bool)
    middle[5:8, 0] = True
    plain = enclosed_gap_colors(_grid(rows, cols), sources, colors, todo, reach=2)
    assert np.isnan(plain[middle.reshape(-1)]).all()
    tube = enclosed_gap_colors(_grid(rows, cols, wrap=True), sources, colors, todo, reach=2, depth=1)
    np.testing.assert_allclose(tube[middle.reshape(-1)], 0.4)


def test_one_odd_cell_at_the_edge_draws_no_streak():
    """A white cell at the gap's lower edge: with depth 3 the median of its column below is the
    cloth's grey; with depth 1 it reaches the gap."""
    rows, cols = 10, 9
    colors = np.full((rows * cols, 3), 0.4)
    hole = np.zeros((rows, cols), bool)
    hole[0:4, 2:7] = True  # at the waistband: the column is read from below only
    colors[4 * cols + 4] = 1.0  # white, just under the gap's middle column
    sources, todo = ~hole.reshape(-1), hole.reshape(-1)
    robust = enclosed_gap_colors(_grid(rows, cols), sources, colors, todo, reach=8, depth=3)
    single = enclosed_gap_colors(_grid(rows, cols), sources, colors, todo, reach=8, depth=1)
    col4 = hole.copy()
    col4[:, [2, 3, 5, 6]] = False
    assert np.abs(robust[col4.reshape(-1)] - 0.4).max() < 1e-12
    assert single[col4.reshape(-1)].min() > 0.45


def test_bad_input_is_a_clear_error():
    nb = _grid(3, 3)
    ok = np.zeros(9, bool)
    with pytest.raises(ValueError, match="expected neighbours"):
        enclosed_gap_colors(nb[:4], ok, np.zeros((9, 3)), ok)
    with pytest.raises(ValueError, match="reach"):
        enclosed_gap_colors(nb, ok, np.zeros((9, 3)), ok, reach=0)
    src = ok.copy()
    src[0] = True
    todo = ~src
    with pytest.raises(ValueError, match="depth"):
        enclosed_gap_colors(nb, src, np.zeros((9, 3)), todo, depth=0)
