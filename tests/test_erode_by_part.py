"""``propagation.erode_by_part``: the seen flags eroded as ``erode`` does, but a limb seen as a narrow
strip (a forearm in a photo) keeps enough of it to colour its unseen side, and never its outermost
ring."""

import numpy as np
import pytest

from reconstruct.appearance.propagation import ERODE_MIN_KEPT, erode, erode_by_part
from reconstruct.appearance.wrap_fill import wrap_fill_colors
from reconstruct.body.parts import PART_INDEX

ROWS, COLS = 40, 24  # a tube's texels: rows along its axis, columns round it


def _tube_neighbours(rows: int = ROWS, cols: int = COLS, offset: int = 0) -> np.ndarray:
    """(rows*cols, 4) 4-neighbours on a tube's grid (columns wrap round), indices shifted by offset."""
    r, c = np.divmod(np.arange(rows * cols), cols)
    out = np.full((rows * cols, 4), -1, np.int64)
    out[:, 0] = r * cols + (c + 1) % cols
    out[:, 1] = r * cols + (c - 1) % cols
    out[r + 1 < rows, 2] = (r * cols + c + cols)[r + 1 < rows]
    out[r > 0, 3] = (r * cols + c - cols)[r > 0]
    return np.where(out >= 0, out + offset, -1)


def _forearm(strip_cols: int = 4, wrist_cols: int = 10, wrist_rows: int = 6):
    """A forearm seen from the front in a photo: a strip ``strip_cols`` texels wide down its length
    (the sleeve), widest at the wrist (the bottom ``wrist_rows`` rows, skin). Returns seen flags
    (rows, cols) and the colours."""
    seen = np.zeros((ROWS, COLS), bool)
    front = COLS * 3 // 4  # the column facing -Y (the camera)
    seen[:, front - strip_cols // 2: front + strip_cols - strip_cols // 2] = True
    seen[:wrist_rows, front - wrist_cols // 2: front + wrist_cols - wrist_cols // 2] = True
    colors = np.tile([0.75, 0.80, 0.85], (ROWS, COLS, 1))  # the sleeve
    colors[:wrist_rows] = [0.85, 0.60, 0.50]  # the wrist's skin
    return seen, colors


def test_a_limb_seen_as_a_strip_keeps_its_one_texel_erosion():
    seen, _ = _forearm()
    seen = seen.ravel()
    nb = _tube_neighbours()
    parts = np.full(len(seen), PART_INDEX["lowerarm.L"])
    two, one = erode(seen, nb, 2), erode(seen, nb, 1)
    assert two.sum() < ERODE_MIN_KEPT * seen.sum() <= one.sum()  # the case this is about
    assert np.array_equal(erode_by_part(seen, nb, parts, 2), one)
    # the torso seen the same way is speckle between another's first hits: eroded in full
    assert np.array_equal(erode_by_part(seen, nb, np.full(len(seen), PART_INDEX["torso"]), 2), two)


def test_a_limb_keeping_enough_erodes_in_full_and_its_outer_ring_always_goes():
    nb = _tube_neighbours()
    parts = np.full(ROWS * COLS, PART_INDEX["shin.R"])
    wide = np.zeros((ROWS, COLS), bool)
    wide[:, 6:18] = True  # 12 texels wide: erosion by 2 keeps 8 of 12 columns
    wide = wide.ravel()
    assert np.array_equal(erode_by_part(wide, nb, parts, 2), erode(wide, nb, 2))
    thin = np.zeros((ROWS, COLS), bool)
    thin[:, 10:12] = True  # 2 texels wide: nothing survives 1 texel either
    thin = thin.ravel()
    assert not erode_by_part(thin, nb, parts, 2).any()  # not the ring itself (level 0)
    assert np.array_equal(erode_by_part(thin, nb, parts, 0), thin)
    assert np.array_equal(erode_by_part(thin, nb, parts, 1), erode(thin, nb, 1))


def test_each_part_is_decided_on_its_own():
    """Two limbs side by side: the strip-seen one falls back to 1 texel, the widely seen one erodes
    by 2; Gaussians of other parts are untouched by either's decision."""
    strip, _ = _forearm()
    wide = np.zeros((ROWS, COLS), bool)
    wide[:, 6:18] = True
    seen = np.concatenate([strip.ravel(), wide.ravel()])
    nb = np.concatenate([_tube_neighbours(), _tube_neighbours(offset=ROWS * COLS)])
    parts = np.repeat([PART_INDEX["lowerarm.L"], PART_INDEX["lowerarm.R"]], ROWS * COLS)
    out = erode_by_part(seen, nb, parts, 2)
    first = parts == PART_INDEX["lowerarm.L"]
    assert np.array_equal(out[first], erode(seen, nb, 1)[first])
    assert np.array_equal(out[~first], erode(seen, nb, 2)[~first])


@pytest.mark.parametrize("by_part", [True, False])
def test_the_back_of_a_strip_seen_sleeve_is_sleeve_not_wrist(by_part):
    """Through the wrap fill: the unseen back of the forearm at the elbow's end takes the sleeve's
    colour with ``erode_by_part``; with ``erode`` alone only the wrist's skin is left as a source,
    and it colours the whole back (the long-skirt photo's left forearm)."""
    seen, colors = _forearm()
    theta = 2 * np.pi * (np.arange(COLS) + 0.5) / COLS  # the strip's middle faces the camera
    z = -0.006 * np.arange(ROWS)  # the wrist at the top row, 24 cm of forearm below it
    pos = np.stack(np.broadcast_arrays(0.04 * np.cos(theta)[None], 0.04 * np.sin(theta)[None], z[:, None]), -1)
    seen, colors, pos = seen.ravel(), colors.reshape(-1, 3), pos.reshape(-1, 3)
    nb = _tube_neighbours()
    parts = np.full(len(seen), PART_INDEX["lowerarm.L"])
    trusted = erode_by_part(seen, nb, parts, 2) if by_part else erode(seen, nb, 2)
    filled = wrap_fill_colors(pos, parts, trusted, colors, nb).numpy()
    back_elbow = (~seen) & (pos[:, 1] > 0.02) & (pos[:, 2] < -0.15)
    assert back_elbow.sum() > 50
    err_sleeve = np.abs(filled[back_elbow] - [0.75, 0.80, 0.85]).max(1)
    if by_part:
        assert np.median(err_sleeve) < 0.02
    else:
        assert np.median(err_sleeve) > 0.15  # the failure the rule is for
