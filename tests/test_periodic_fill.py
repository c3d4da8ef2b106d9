"""A pattern repeating round a tube carried on round its unseen side (reconstruct.appearance.
periodic_fill): the period of checks seen on the front half of a tube, the continuation against
the truth (and against the mirror image, which shifts the phase), no period for solid cloth,
stripes round the tube or slowly varying shading, two tubes each with its own period, and the wrap
fill using it for a garment layer's grid."""

import numpy as np
import pytest

from reconstruct.appearance.periodic_fill import continue_layer, continue_round, tube_period
from reconstruct.appearance.wrap_fill import WrapFillConfig, wrap_fill_colors
from reconstruct.avatar.garment_layer import GARMENT_PART

A, B = np.array([0.7, 0.3, 0.2]), np.array([0.2, 0.6, 0.3])


def checks(R, C, period, row_period=9.0, phase=0.37):
    """(R,C,3) checks: smooth squares repeating every ``period`` columns and ``row_period`` rows."""
    r, c = np.meshgrid(np.arange(R), np.arange(C), indexing="ij")
    a = 0.5 + 0.5 * np.tanh(4 * np.sin(2 * np.pi * (c + phase) / period))
    b = 0.5 + 0.5 * np.tanh(4 * np.sin(2 * np.pi * r / row_period))
    t = 0.5 * (a + b)
    return A * (1 - t[..., None]) + B * t[..., None]


def front_half(R, C, half_width):
    """Seen: the columns within ``half_width`` of column 0 (the front), wrapping."""
    c = np.arange(C)
    d = np.minimum(c, C - c)
    return np.broadcast_to(d <= half_width, (R, C)).copy()


def test_period_and_continuation_of_checks_against_the_truth():
    R, C = 40, 92
    P = C / 12  # twelve repeats round the tube, no seam
    truth = checks(R, C, P)
    seen = front_half(R, C, 24)
    rng = np.random.default_rng(0)
    noisy = truth + rng.normal(0, 0.02, truth.shape) * seen[..., None]
    got = tube_period(noisy, seen)
    assert got is not None and abs(got - P) < 0.1
    out, done = continue_round(noisy, seen, got)
    back = ~seen
    assert done[back].all() and not done[seen].any()
    err = np.abs(out - truth)[back].mean()
    # the mirror image through the coronal plane (column c -> C/2 - c) gets the phase wrong
    mirror_cols = (C // 2 - np.arange(C)) % C
    mirrored = noisy[:, mirror_cols]
    err_mirror = np.abs(mirrored - truth)[back].mean()
    assert err < 0.04 and err_mirror > 3 * err


@pytest.mark.parametrize("kind", ["solid", "stripes", "shading"])
def test_no_period_without_a_repeating_pattern(kind):
    R, C = 40, 92
    r, c = np.meshgrid(np.arange(R), np.arange(C), indexing="ij")
    rng = np.random.default_rng(1)
    if kind == "solid":
        col = np.broadcast_to(A, (R, C, 3)) + rng.normal(0, 0.03, (R, C, 3))
    elif kind == "stripes":  # round the tube: the same colour along each row
        t = (np.sin(2 * np.pi * r / 6.0) > 0).astype(float)
        col = A * (1 - t[..., None]) + B * t[..., None] + rng.normal(0, 0.02, (R, C, 3))
    else:  # a photo's light: bright in front, darker round the sides, folds along the rows
        light = 0.6 + 0.4 * np.cos(2 * np.pi * c / C) + 0.1 * np.sin(2 * np.pi * r / 11.0)
        col = A * light[..., None] + rng.normal(0, 0.02, (R, C, 3))
    seen = front_half(R, C, 24)
    assert tube_period(col, seen) is None
    # nothing to continue: the wrap fill's layer is left to the other steps
    out, done = continue_layer(col.reshape(-1, 3), seen.reshape(-1), (R, C), 1)
    assert not done.any() and np.array_equal(out, col.reshape(-1, 3))


def test_two_tubes_each_with_its_own_period_and_shape_errors():
    R, C = 30, 96  # two tubes of 48 columns (trousers)
    left, right = checks(R, 48, 48 / 8), checks(R, 48, 48 / 6, phase=1.1)
    col = np.concatenate([left, right], 1)
    seen = np.concatenate([front_half(R, 48, 13), front_half(R, 48, 13)], 1)
    out, done = continue_layer(col.reshape(-1, 3), seen.reshape(-1), (R, C), 2)
    out = out.reshape(R, C, 3)
    assert done.reshape(R, C)[~seen].all()
    assert np.abs(out - col)[~seen].mean() < 0.03
    with pytest.raises(ValueError, match="for a 30x96 grid"):
        continue_layer(col.reshape(-1, 3)[:-1], seen.reshape(-1)[:-1], (R, C), 2)
    with pytest.raises(ValueError, match="do not split into 5 tubes"):
        continue_layer(col.reshape(-1, 3), seen.reshape(-1), (R, C), 5)


def test_wrap_fill_carries_the_layers_checks_round_by_periods():
    R, C = 30, 92
    truth = checks(R, C, C / 12)
    th = 2 * np.pi * np.arange(C) / C
    z = -0.02 * np.arange(R)
    pos = np.stack([np.broadcast_to(0.2 * np.sin(th), (R, C)), np.broadcast_to(-0.2 * np.cos(th), (R, C)),
                    np.broadcast_to(z[:, None], (R, C))], -1).reshape(-1, 3)
    parts = np.full(R * C, GARMENT_PART)
    seen = front_half(R, C, 24).reshape(-1)
    col = truth.reshape(-1, 3)
    with_grid = wrap_fill_colors(pos, parts, seen, col, None, layer_grid=(R, C, 1)).numpy()
    without = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen
    err = np.abs(with_grid - col)[back].mean()
    assert err < 0.03 and np.abs(without - col)[back].mean() > 2 * err
    np.testing.assert_allclose(with_grid[seen], col[seen].astype(np.float32), atol=1e-6)
    # a region under a redo keeps the low-frequency fill (no copied detail)
    redo = back & (np.arange(R * C) // C < 10)
    redone = wrap_fill_colors(pos, parts, seen, col, None, no_mirror=redo, layer_grid=(R, C, 1)).numpy()
    # (the low fill of the layer's own rows: the same with the mirror off everywhere)
    plain = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(max_mirror_distance=0.0), no_mirror=redo,
                             layer_grid=(R, C, 1)).numpy()
    np.testing.assert_array_equal(redone[redo], plain[redo])
    np.testing.assert_array_equal(redone[back & ~redo], with_grid[back & ~redo])
    # a solid layer: the grid changes nothing
    solid = np.broadcast_to(A, (R * C, 3))
    np.testing.assert_array_equal(wrap_fill_colors(pos, parts, seen, solid, None, layer_grid=(R, C, 1)).numpy(),
                                  wrap_fill_colors(pos, parts, seen, solid, None).numpy())


def _read_whole_periods(colors, seen, period):
    """The old continuation, as a reference: each unseen Gaussian read (linearly, between two seen
    columns) the smallest whole number of periods along its row."""
    R, C, _ = colors.shape
    out = colors.copy()
    for r in range(R):
        for c in np.flatnonzero(~seen[r]):
            for k in range(1, int(np.ceil(C / period)) + 1):
                hit = False
                for sign in (-1, 1):
                    q = c + sign * k * period
                    lo = int(np.floor(q)) % C
                    hi = (lo + 1) % C
                    if seen[r, lo] and seen[r, hi]:
                        w = q - np.floor(q)
                        out[r, c] = colors[r, lo] * (1 - w) + colors[r, hi] * w
                        hit = True
                        break
                if hit:
                    break
    return out


@pytest.mark.parametrize("period", [3.6, 4.0])
def test_checks_finer_than_five_columns_are_folded_at_full_contrast(period):
    """Checks repeating every 3.6 columns (the wide trousers' legs): the period is found, and the
    fold carries them round at nearly their contrast, where a read between two columns a whole
    number of periods on blurs the lines."""
    R, C = 40, 92
    truth = checks(R, C, period, phase=0.21)
    seen = front_half(R, C, 24)
    got = tube_period(truth, seen)
    assert got is not None and abs(got - period) < 0.05 * period
    out, done = continue_round(truth, seen, got)
    back = ~seen
    assert done[back].all() and not done[seen].any()
    np.testing.assert_array_equal(out[seen], truth[seen])
    err = np.abs(out - truth)[back].mean()
    err_read = np.abs(_read_whole_periods(truth, seen, got) - truth)[back].mean()
    assert err < 0.02 and err_read > 1.5 * err


def test_a_period_near_the_grids_limit():
    """Under ``MIN_PERIOD`` (2.5 columns) a period is not carried; just over it, it is, nearly
    exactly (the rows' phases fill the period)."""
    R, C = 40, 92
    seen = front_half(R, C, 24)
    assert tube_period(checks(R, C, 2.27), seen) is None
    truth = checks(R, C, 2.6)
    got = tube_period(truth, seen)
    assert got is not None and abs(got - 2.6) < 0.05
    out, done = continue_round(truth, seen, got)
    assert done[~seen].all() and np.abs(out - truth)[~seen].mean() < 0.015


def test_refine_period_against_the_truth():
    from reconstruct.appearance.periodic_fill import refine_period
    R, C = 40, 92
    truth = checks(R, C, 3.55)
    seen = front_half(R, C, 24)
    assert abs(refine_period(truth, seen, 3.62) - 3.55) < 0.01
    assert abs(refine_period(truth, seen, 3.50) - 3.55) < 0.01
    assert abs(refine_period(truth, seen, 3.90) - 3.55) < 0.01  # 10 % off, as the shift estimate was on trousers seed 0


def test_diagonal_stripes_fold_row_by_row():
    """Stripes whose phase moves along the rows (diagonal round the tube) share no waveform across
    the rows: the rows fold alone, and the back continues each row's own phase."""
    R, C = 40, 92
    r, c = np.meshgrid(np.arange(R), np.arange(C), indexing="ij")
    t = 0.5 + 0.5 * np.tanh(3 * np.sin(2 * np.pi * (c + 0.45 * r) / (C / 12)))
    truth = A * (1 - t[..., None]) + B * t[..., None]
    seen = front_half(R, C, 24)
    noisy = truth + np.random.default_rng(3).normal(0, 0.02, truth.shape) * seen[..., None]
    got = tube_period(noisy, seen)
    assert got is not None and abs(got - C / 12) < 0.3
    out, done = continue_round(noisy, seen, got)
    back = ~seen
    assert done[back].all()
    err = np.abs(out - truth)[back].mean()
    # the rows' mean colour, which a shared waveform would come to here
    flat = np.abs(truth[seen].mean(0) - truth[back]).mean()
    assert err < 0.03 and flat > 4 * err


def test_one_band_seen_once_is_no_period():
    """An open jacket seen from the front of a photo: the shirt between the flaps is one light band
    with the cloth on either side, seen over less than two of any period it could have. Shifting by
    nearly the seen width pairs one flap with the other (alike) and half of it the shirt with a
    flap (unlike), which alone looks like a period; no pair two periods apart was seen, so the
    pattern was never seen to repeat, and nothing is carried round the back. A band seen over
    more than two of its periods still is."""
    R, C = 47, 92
    c = np.arange(C)
    d = np.minimum(c, C - c)
    band = (d <= 5).astype(float)
    rng = np.random.default_rng(2)
    col = np.broadcast_to(A * 0.4 * (1 - band[:, None]) + np.array([0.9, 0.9, 0.9]) * band[:, None], (R, C, 3))
    col = col + rng.normal(0, 0.02, (R, C, 3))
    seen = front_half(R, C, 15)
    assert tube_period(col, seen) is None
    out, done = continue_layer(col.reshape(-1, 3), seen.reshape(-1), (R, C), 1)
    assert not done.any()
    # the same band repeating every 23 columns, seen over 2.7 periods: a period
    rep = np.minimum(c % 23, 23 - c % 23) <= 5
    col2 = np.where(rep[None, :, None], np.array([0.9, 0.9, 0.9]), A * 0.4) + rng.normal(0, 0.02, (R, C, 3))
    got = tube_period(col2, front_half(R, C, 31))
    assert got is not None and abs(got - 23) < 0.5


def test_a_pattern_seen_over_under_three_periods_is_no_period(monkeypatch):
    """A pattern must be seen to repeat: the seen pairs two periods apart must be at least
    ``REPEAT_SHARE`` of those half a period apart (a seen width of about three periods). A video
    of a one-colour coat, seen over 39 columns from the front, read a period of 17.6 columns from
    its button column and the open front's edges; the only pairs two periods apart were on the
    plain flanks, and the buttons were carried round the back twice."""
    from reconstruct.appearance import periodic_fill
    R, C = 58, 92
    seen = front_half(R, C, 19)  # 39 columns
    wide = checks(R, C, 13.0)  # 3 periods seen, not quite (the estimate is 13.5)
    assert tube_period(wide, seen) is None
    out, done = continue_layer(wide.reshape(-1, 3), seen.reshape(-1), (R, C), 1)
    assert not done.any()
    got = tube_period(checks(R, C, 10.0), seen)  # 3.9 periods seen: a period
    assert got is not None and abs(got - 10.0) < 1.0
    # without the share (pairs two periods apart counted only against MIN_PAIRS) it was one
    monkeypatch.setattr(periodic_fill, "REPEAT_SHARE", 0.0)
    got = tube_period(wide, seen)
    assert got is not None and abs(got - 13.0) < 1.0
