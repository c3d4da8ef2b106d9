"""The wrap-around fill (reconstruct.appearance.wrap_fill) on hand-built surfaces with known answers:
a striped cylinder with a front emblem (the back gets the stripes at the right heights, none of
the emblem), checks that vary left-right (the back continues them with their phase), and a head
with a face in front and hair at the sides (the back gets hair, not skin)."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree
import torch

from reconstruct.avatar.garment_layer import GARMENT_PART
from reconstruct.body.parts import PART_INDEX
from reconstruct.appearance.hair import hair_sources
from reconstruct.appearance.wrap_fill import (WrapFillConfig, _left_right_mirror, column_middle, height_profile,
                                              long_hair_colors, wrap_fill_colors)

RED, WHITE, BLUE, SKIN, HAIR, YELLOW, GREEN = (np.array(c, float) for c in (
    (0.8, 0.1, 0.1), (0.9, 0.9, 0.9), (0.1, 0.2, 0.8), (0.9, 0.7, 0.6), (0.2, 0.1, 0.05), (1.0, 0.9, 0.0),
    (0.1, 0.4, 0.3)))


def cylinder(radius=0.15, height=0.5, n_theta=96, n_z=100, z0=1.0):
    """Points on a vertical cylinder; theta = 0 faces the front (-Y). Returns positions, theta."""
    th, z = np.meshgrid(np.linspace(-np.pi, np.pi, n_theta, endpoint=False), np.linspace(z0, z0 + height, n_z))
    th, z = th.ravel(), z.ravel()
    pos = np.c_[radius * np.sin(th), -radius * np.cos(th), z]
    return pos, th


def seen_front(th, half_angle_deg=100.0):
    return np.abs(np.degrees(th)) <= half_angle_deg


def stripes(z, period=0.08):
    return np.where(np.sin(z * 2 * np.pi / period) > 0, 1.0, 0.0)


def test_stripes_carried_by_height_and_emblem_left_out():
    pos, th = cylinder()
    t = stripes(pos[:, 2])[:, None]
    truth = RED * (1 - t) + WHITE * t
    col = truth.copy()
    emblem = (np.abs(pos[:, 0] - 0.05) < 0.06) & (np.abs(pos[:, 2] - 1.3) < 0.06) & (np.abs(np.degrees(th)) < 60)
    col[emblem] = YELLOW
    seen = seen_front(th)
    parts = np.full(len(pos), PART_INDEX["torso"])
    out = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0)).numpy()
    back = ~seen
    # away from the stripe edges (where a 1 cm slab mixes both), the back shows the stripe of its height
    phase = (pos[:, 2] % 0.08) / 0.08
    interior = back & (np.abs(phase - 0.25) < 0.15) | back & (np.abs(phase - 0.75) < 0.15)
    assert np.abs(out[interior] - truth[interior]).max() < 1e-6
    # no emblem colour anywhere on the back (it never reaches the sides)
    assert np.linalg.norm(out[back] - YELLOW, axis=1).min() > 0.3
    # seen colours unchanged
    np.testing.assert_allclose(out[seen], col[seen].astype(np.float32), atol=1e-6)


def _striped_coat_layer(R=60, C=92, row_step=0.014, rows_per_stripe=4):
    """A garment layer's row-major grid round a tube (rows one height each, ``row_step`` apart,
    theta = 0 facing the front): green and purple stripes of ``rows_per_stripe`` rows, an open
    front whose lining (a purple a little darker than the stripes') shows down the middle at
    every height, seen over the front half."""
    GREEN, PURPLE = np.array([0.45, 0.6, 0.35]), np.array([0.3, 0.2, 0.27])
    th = 2 * np.pi * np.arange(C) / C - np.pi
    z = 1.2 - row_step * np.arange(R)
    pos = np.stack([np.broadcast_to(0.2 * np.sin(th), (R, C)), np.broadcast_to(-0.2 * np.cos(th), (R, C)),
                    np.broadcast_to(z[:, None], (R, C))], -1).reshape(-1, 3)
    green_row = (np.arange(R) // rows_per_stripe) % 2 == 0
    col = np.where(green_row[:, None, None], GREEN, PURPLE) * np.ones((R, C, 1))
    col[:, np.abs(np.degrees(th)) < 12] = PURPLE - 0.06  # the lining, within the palette tolerance of PURPLE
    seen = np.broadcast_to(np.abs(np.degrees(th)) <= 100, (R, C))
    back_middle = np.broadcast_to(np.abs(np.degrees(th)) > 168, (R, C))
    return pos, col.reshape(-1, 3), seen.reshape(-1), back_middle, green_row, GREEN


def test_layer_mirror_is_gated_by_its_own_row_not_by_stripes_nearby():
    """On a garment layer the mirrored colour must be one the band shows in the same row: stripes
    put both colours within ``palette_height`` of every height, and the open front's dark lining,
    mirrored to the back through the coronal plane, passed the gate between two green stripes (a
    dark band down the back of coat seed 2)."""
    R, C = 60, 92
    pos, col, seen, back_middle, green_row, GREEN = _striped_coat_layer(R, C)
    parts = np.full(R * C, GARMENT_PART)
    cfg = WrapFillConfig(smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg, layer_grid=(R, C, 1)).numpy().reshape(R, C, 3)
    # the middle of green stripes (a row in from each edge: the 1 cm slab of the low fill mixes them)
    inner = green_row & np.r_[False, green_row[:-1]] & np.r_[green_row[1:], False]
    mid = back_middle.reshape(R, C) & inner[:, None]
    assert mid.sum() > 50
    np.testing.assert_allclose(out[mid], np.broadcast_to(GREEN, out[mid].shape), atol=1e-6)
    # the same gate over palette_height (8 cm, the body's) lets the lining through there
    wide = WrapFillConfig(smooth_sweeps=0, layer_palette_rows=cfg.palette_height / 0.014)
    old = wrap_fill_colors(pos, parts, seen, col, None, wide, layer_grid=(R, C, 1)).numpy().reshape(R, C, 3)
    assert np.abs(old[mid] - GREEN).max() > 0.2
    # without the grid the layer is gated like a body part (palette_height)
    np.testing.assert_array_equal(wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy().reshape(R, C, 3)[mid],
                                  old[mid])
    np.testing.assert_allclose(out.reshape(-1, 3)[seen], col[seen].astype(np.float32), atol=1e-6)


def test_layer_low_fill_takes_its_own_rows_band():
    """On a garment layer the same-height median reads the band of the Gaussian's own row. A row's
    band (the seen cloth within ``band`` of the unseen side) holds fewer than ``k`` Gaussians, and
    the slab widened over the rows above and below mixed stripes a row or two wide (coat seed 2:
    the back's stripes came out 0.1-0.2 duller than the front's)."""
    R, C = 40, 92
    pos, col, seen, back_middle, green_row, GREEN = _striped_coat_layer(R, C, rows_per_stripe=1)
    parts = np.full(R * C, GARMENT_PART)
    cfg = WrapFillConfig(smooth_sweeps=0, max_mirror_distance=0.0)  # the low-frequency fill alone
    d, _ = cKDTree(pos[~seen]).query(pos[seen])
    band_rows = (np.flatnonzero(seen)[d <= cfg.band]) // C
    assert np.bincount(band_rows, minlength=R).max() < cfg.k  # each row's own band is short of k
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg, layer_grid=(R, C, 1)).numpy().reshape(R, C, 3)
    back = ~seen.reshape(R, C)
    truth = col.reshape(R, C, 3)
    np.testing.assert_allclose(out[back], truth[back].astype(np.float32), atol=1e-6)
    # the slab widened over the neighbouring rows blends the two colours
    old = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0, max_mirror_distance=0.0,
                           layer_row_median=False), layer_grid=(R, C, 1)).numpy().reshape(R, C, 3)
    assert np.abs(old[back] - truth[back]).max(1).mean() > 0.05
    # without the grid, the slab as on a body part
    np.testing.assert_array_equal(wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy().reshape(R, C, 3), old)


def _photo_layer(R=60, C=92, shade=0.0, seed=0, rows_per_stripe=4):
    """``_striped_coat_layer`` seen as in a photo (to 85 degrees: never behind its centre), each
    row lit a little differently (a random brightness within +-``shade``), with a dark scarf down
    the middle of the front over rows 10-30 and darker folds on the front's sides."""
    pos, col, _, _, green_row, GREEN = _striped_coat_layer(R, C, rows_per_stripe=rows_per_stripe)
    col = col.reshape(R, C, 3).copy()
    th = np.degrees(2 * np.pi * np.arange(C) / C - np.pi)
    col[:, np.abs(th) < 12] = col[:, np.abs(th) >= 170][:, :1]  # no lining: the stripes all round
    truth = col.copy()
    col += np.random.default_rng(seed).uniform(-shade, shade, R)[:, None, None]
    col[10:30, np.abs(th) < 15] = (0.1, 0.1, 0.5)  # the scarf
    col[:, (np.abs(th) > 50) & (np.abs(th) < 60)] *= 0.7  # folds
    seen = np.broadcast_to(np.abs(th) <= 85, (R, C)).reshape(-1)
    return pos, np.clip(col, 0, 1).reshape(-1, 3), seen, truth, green_row


def test_a_front_only_layer_is_filled_by_rows():
    """A photo's layer (never seen behind its centre) takes its rows' seen medians round the back:
    the stripes at their heights, none of the front's scarf or folds. The band, the mirror and the
    200 nearest of a body part wash the stripes out."""
    R, C = 60, 92
    pos, col, seen, truth, green_row = _photo_layer(R, C)
    parts = np.full(R * C, GARMENT_PART)
    back = ~seen.reshape(R, C)
    err = lambda out: np.abs(out.reshape(R, C, 3)[back] - truth[back]).max(1)  # noqa: E731
    out = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(), layer_grid=(R, C, 1)).numpy()
    old = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(layer_profile_rows=0),
                           layer_grid=(R, C, 1)).numpy()
    # a stripe's edge rows are smoothed by the grid sweeps; the rest is the stripe's colour
    inner = green_row & np.r_[False, green_row[:-1]] & np.r_[green_row[1:], False]
    inner |= ~green_row & np.r_[False, ~green_row[:-1]] & np.r_[~green_row[1:], False]
    mid = (back & inner[:, None])[back]
    assert np.median(err(out)[mid]) < 0.01 and err(out)[mid].max() < 0.05
    assert np.median(err(old)[mid]) > 0.05
    np.testing.assert_allclose(out[seen], col[seen].astype(np.float32), atol=1e-6)


def _skirt_grid(R: int, C: int) -> tuple[np.ndarray, np.ndarray]:
    """A layer's grid as a photo's skirt: (C,) angles from the front (-pi at column 0) and (R*C, 3)
    row-major positions on a 25 cm tube, rows 1.4 cm apart down from 1 m."""
    th = 2 * np.pi * np.arange(C) / C - np.pi
    z = 1.0 - 0.014 * np.arange(R)
    pos = np.stack([np.broadcast_to(0.25 * np.sin(th), (R, C)), np.broadcast_to(-0.25 * np.cos(th), (R, C)),
                    np.broadcast_to(z[:, None], (R, C))], -1).reshape(-1, 3)
    return th, pos


def test_a_front_only_layers_rows_read_the_sources_before_erosion():
    """A photo's cloth is speckled: light first hits (sheen) between dark folds. The trusted flags,
    eroded, keep the dark folds' middles only; the rows' medians are read on ``row_seen`` (the
    flags before erosion) and the back takes the cloth's colour, not the folds' (the long-skirt
    photo's navy skirt came out black behind). Not in rows whose first hits cover under
    ``row_seen_share`` of the front: there they are what shows through the layer; nor in colours
    the trusted flags show nowhere near (``row_seen_rows``): a sleeve hanging in front."""
    R, C = 30, 92
    NAVY, FOLD = np.array([0.05, 0.1, 0.3]), np.array([0.01, 0.01, 0.03])
    th, pos = _skirt_grid(R, C)
    front = np.broadcast_to(np.abs(np.degrees(th)) <= 85, (R, C))
    fold = np.broadcast_to((np.arange(C) // 5) % 3 == 0, (R, C))  # a third of the columns, in 5-wide folds
    col = np.where(fold[..., None], FOLD, NAVY).reshape(-1, 3)
    seen = front.reshape(-1)
    # erosion keeps the folds' middles and a few of the cloth's: its median is the folds'
    middle = np.broadcast_to((np.arange(C) % 5 == 2), (R, C))
    trusted = (front & middle & (fold | ((np.arange(C) // 5) % 6 == 1))).reshape(-1)
    parts = np.full(R * C, GARMENT_PART)
    cfg = WrapFillConfig(smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, trusted, col, None, cfg, layer_grid=(R, C, 1), row_seen=seen).numpy()
    old = wrap_fill_colors(pos, parts, trusted, col, None, cfg, layer_grid=(R, C, 1)).numpy()
    back = ~seen
    np.testing.assert_allclose(out[back], np.tile(NAVY, (back.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(old[back], np.tile(FOLD, (back.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(out[trusted], col[trusted], atol=1e-6)  # the trusted keep their own
    # rows below the front hem: a few first hits on the layer show the trousers through it. Under a
    # third of the row's front, they are not read (the eroded flags are): no trousers round the back
    TROUSERS = np.array([0.3, 0.3, 0.3])
    low = np.arange(R * C) // C >= R - 5
    strip = low & (np.abs(np.degrees(np.tile(th, R))) < 15)  # 11 of the row's 43 in front
    col2 = col.copy()
    col2[strip] = TROUSERS
    seen2 = (seen & ~low) | strip
    trusted2 = trusted & ~low
    fill = lambda share: wrap_fill_colors(pos, parts, trusted2, col2, None, WrapFillConfig(  # noqa: E731
        smooth_sweeps=0, row_seen_share=share, row_seen_rows=None), layer_grid=(R, C, 1), row_seen=seen2).numpy()
    assert np.abs(fill(1 / 3)[low & back] - TROUSERS).max(1).min() > 0.2
    np.testing.assert_allclose(fill(0.0)[low & back], np.tile(TROUSERS, ((low & back).sum(), 1)), atol=1e-6)
    # sleeves hanging in front of the cloth over half a row's front: first hits in a colour the
    # trusted flags show nowhere near are not the cloth's
    hips = (np.arange(R * C) // C >= 10) & (np.arange(R * C) // C < 13)
    sleeve = hips & front.reshape(-1) & (np.abs(np.degrees(np.tile(th, R))) > 30)
    col3 = col.copy()
    col3[sleeve] = WHITE
    trusted3 = trusted & ~sleeve
    fill3 = lambda rows: wrap_fill_colors(pos, parts, trusted3, col3, None, WrapFillConfig(  # noqa: E731
        smooth_sweeps=0, row_seen_rows=rows), layer_grid=(R, C, 1), row_seen=seen).numpy()
    np.testing.assert_allclose(fill3(2)[hips & back], np.tile(NAVY, ((hips & back).sum(), 1)), atol=1e-6)
    assert np.abs(fill3(None)[hips & back] - WHITE).max(1).max() < 0.05


def test_a_front_only_layers_row_seen_on_one_side_keeps_its_own_colour():
    """A photo's layer over a blouse and a high-waisted skirt: the skirt's top rows are seen on
    one side of the layer only (the other hidden), and the rows just above them show the blouse's
    white on both sides. No colour of those rows is matched on the other side within the palette's
    height, so the both-sides test drops them all but a sleeve's white at their ends; the rows keep
    their own navy round the back (with the test alone they took the white: the long-skirt photo at
    380 px)."""
    R, C = 30, 92
    NAVY = np.array([0.05, 0.1, 0.3])
    th, pos = _skirt_grid(R, C)
    row = np.arange(R)[:, None]
    front = np.abs(np.degrees(th)) <= 85
    col = np.where((row < 10)[..., None], WHITE, NAVY) * np.ones((R, C, 1))
    one_side = (row >= 10) & (row < 20)
    seen = front & ~(one_side & (th > 0))  # the skirt's top rows seen on one side of the middle only
    edge = np.flatnonzero(front)[:3]
    col[10:20, edge] = WHITE  # and a sleeve's white at their ends: it passes the test, 3 of a row's 43
    parts = np.full(R * C, GARMENT_PART)
    cfg = WrapFillConfig(smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen.reshape(-1), col.reshape(-1, 3), None, cfg,
                           layer_grid=(R, C, 1)).numpy().reshape(R, C, 3)
    back = ~front & np.ones((R, 1), bool)
    skirt_top = back & one_side
    np.testing.assert_allclose(out[skirt_top], np.tile(NAVY, (skirt_top.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(out[back & (row < 10)], np.tile(WHITE, ((back & (row < 10)).sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(out[back & (row >= 20)], np.tile(NAVY, ((back & (row >= 20)).sum(), 1)), atol=1e-6)


def test_a_front_only_layers_rows_are_smoothed_where_alike():
    """Shading from row to row (within the palette tolerance) is averaged down the layer; stripes
    (further apart than it) are not."""
    R, C = 60, 92
    pos, col, seen, truth, green_row = _photo_layer(R, C, shade=0.05, rows_per_stripe=10)
    parts = np.full(R * C, GARMENT_PART)
    back = ~seen.reshape(R, C)
    rows = lambda out: np.stack([out.reshape(R, C, 3)[r][back[r]].mean(0) for r in range(R)])  # noqa: E731
    smooth = rows(wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0),
                                   layer_grid=(R, C, 1)).numpy())
    raw = rows(wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0, layer_profile_rows=1),
                                layer_grid=(R, C, 1)).numpy())
    same = green_row[1:] == green_row[:-1]  # neighbouring rows of one stripe
    rough = lambda c: np.abs(np.diff(c, axis=0)).max(1)[same].mean()  # noqa: E731
    assert rough(smooth) < 0.4 * rough(raw)
    # the stripes stay two colours: every back row is nearer its own stripe's colour than the other's
    own, other = truth[:, 0], truth[np.r_[10:R, 0:10], 0]
    assert (np.abs(smooth - own).sum(1) < np.abs(smooth - other).sum(1)).all()


def test_row_profile_takes_a_rows_shading_for_shading_not_a_stripe():
    """A row in shadow (the coat photo's top rows under its folded arms: 0.15 against 0.33, much
    the same in each channel) is averaged with its neighbours once half its mean difference is
    taken off; compared channel by channel it is a stripe and stays. A black stripe between white
    rows, or a change of hue, stays either way."""
    from reconstruct.appearance.wrap_fill import _row_profile
    coat, shade = np.array([0.33, 0.33, 0.27]), np.array([0.15, 0.15, 0.11])
    rows = np.repeat(np.arange(12), 3)  # three queries a row
    col = np.tile(coat, (36, 1))
    col[rows == 0] = shade
    tol = WrapFillConfig().palette_tolerance
    got = _row_profile(rows, col, 5, tol, luminance=0.5)
    np.testing.assert_allclose(got[rows == 0], np.tile((shade + 5 * coat) / 6, (3, 1)), atol=1e-12)
    np.testing.assert_allclose(got[rows == 6], np.tile(coat, (3, 1)), atol=1e-12)  # out of the shade's reach
    np.testing.assert_allclose(_row_profile(rows, col, 5, tol, luminance=1.0)[rows == 0], col[rows == 0])
    for dark in ((0.05, 0.05, 0.05), (0.33, 0.10, 0.27)):  # a black stripe on white; a magenta one on green
        base = np.tile((0.9, 0.9, 0.9) if dark[1] == 0.05 else coat, (36, 1))
        base[rows == 0] = dark
        np.testing.assert_allclose(_row_profile(rows, base, 5, tol, luminance=0.5)[rows == 0], base[rows == 0])


def test_layer_row_with_a_short_band_leaves_out_a_colour_seen_on_one_side(monkeypatch):
    """A row whose band is short of ``k`` takes the nearest of its own seen Gaussians, but only in
    colours the cloth shows on both sides at that height: the green-jacket photo's open front showed
    the white shirt and collar at one flap's edge in its top rows, and the back took a white patch
    there."""
    from reconstruct.appearance import wrap_fill
    R, C = 20, 92
    GREEN = np.array([0.1, 0.3, 0.25])
    th = 2 * np.pi * np.arange(C) / C - np.pi
    z = 1.2 - 0.014 * np.arange(R)
    pos = np.stack([np.broadcast_to(0.2 * np.sin(th), (R, C)), np.broadcast_to(-0.2 * np.cos(th), (R, C)),
                    np.broadcast_to(z[:, None], (R, C))], -1).reshape(-1, 3)
    deg = np.broadcast_to(np.degrees(th), (R, C))
    col = np.tile(GREEN, (R, C, 1))
    shirt = (np.arange(R)[:, None] < 6) & (deg > 60) & (deg <= 100)  # one side, at the seen edge
    col[shirt] = WHITE
    seen = (np.abs(deg) <= 100).reshape(-1)
    parts = np.full(R * C, GARMENT_PART)
    cfg = WrapFillConfig(smooth_sweeps=0, max_mirror_distance=0.0)  # the low-frequency fill alone
    out = wrap_fill_colors(pos, parts, seen, col.reshape(-1, 3), None, cfg, layer_grid=(R, C, 1)).numpy()
    back = ~seen
    np.testing.assert_allclose(out[back], np.tile(GREEN, (back.sum(), 1)), atol=1e-6)
    # colours from either side in the row's pool (before): the shirt's top rows are carried round
    monkeypatch.setattr(wrap_fill, "_on_both_sides", lambda band_pos, *a: np.ones(len(band_pos), bool))
    old = wrap_fill_colors(pos, parts, seen, col.reshape(-1, 3), None, cfg, layer_grid=(R, C, 1)).numpy()
    top_back = back & (np.arange(R * C) // C < 6)
    assert np.abs(old[top_back] - WHITE).max(1).min() < 0.05


def test_a_part_with_a_few_trusted_edge_gaussians_takes_its_twins_colours():
    """A hand seen as a thin strip keeps a few trusted Gaussians after the erosion, at its edge and
    darkened there; with fewer than ``twin_below`` of them it is filled from its twin (mirrored in
    x), which shows its skin: the long-skirt photo's left hand came out dark red from behind."""
    a, th = cylinder(radius=0.03, height=0.1, n_theta=24, n_z=12)
    pos = np.r_[a + [0.3, 0, 0], a + [-0.3, 0, 0]]
    parts = np.r_[np.full(len(a), PART_INDEX["hand.L"]), np.full(len(a), PART_INDEX["hand.R"])]
    col = np.tile(SKIN, (len(pos), 1))
    strip = np.abs(np.degrees(th)) < 10  # the left hand: one column of 12 trusted Gaussians
    seen = np.r_[strip, seen_front(th)]
    col[:len(a)][strip] = HAIR  # its trusted edge is dark
    cfg = WrapFillConfig(smooth_sweeps=0)
    assert cfg.k <= strip.sum() < cfg.twin_below  # the case the rule is for
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    back = np.r_[~strip, np.zeros(len(a), bool)]
    np.testing.assert_allclose(out[back], np.tile(SKIN, (back.sum(), 1)), atol=1e-6)
    # with the twin borrowed only below k (before), the dark edge is carried round
    old = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0, twin_below=0, twin_share=0.0)).numpy()
    assert np.abs(old[back] - SKIN).max(1).mean() > 0.3


def test_emblem_reaching_one_side_is_left_out():
    pos, th = cylinder()
    col = np.tile(BLUE, (len(pos), 1))
    # an off-centre emblem reaching round the left side up to the visibility boundary
    deg = np.degrees(th)
    emblem = (deg > 30) & (deg < 100) & (np.abs(pos[:, 2] - 1.25) < 0.07)
    col[emblem] = YELLOW
    seen = seen_front(th)
    out = wrap_fill_colors(pos, np.zeros(len(pos), int), seen, col, None, WrapFillConfig(smooth_sweeps=0)).numpy()
    np.testing.assert_allclose(out[~seen], np.tile(BLUE, ((~seen).sum(), 1)), atol=1e-6)


def test_checks_continue_with_their_left_right_phase():
    pos, th = cylinder()
    period = 0.1
    a = np.sin(pos[:, 2] * 2 * np.pi / period) > 0
    b = np.sin(pos[:, 0] * 2 * np.pi / period) > 0
    truth = np.where((a ^ b)[:, None], RED, WHITE)  # a function of x and z: the back is the front's mirror
    seen = seen_front(th, 95)
    out = wrap_fill_colors(pos, np.zeros(len(pos), int), seen, truth, None, WrapFillConfig(smooth_sweeps=0)).numpy()
    back = ~seen
    agree = np.linalg.norm(out[back] - truth[back], axis=1) < 1e-6
    assert agree.mean() > 0.9


def test_checks_continue_on_a_leaning_tube_mirrored_through_its_columns():
    """A torso leans and is deeper at the chest than at the shoulders: its front and back are not
    mirror images through one plane. Mirrored through the middle of each column the back still
    continues the front's checks; through the part's centre plane the mirror images fall more than
    ``max_mirror_distance`` off the front at the top and the bottom, and the back takes the
    same-height median there instead."""
    pos, th = cylinder()
    pos[:, 1] += 0.6 * (pos[:, 2] - 1.25)  # the axis leans 30 cm over the tube's height
    period = 0.1
    a = np.sin(pos[:, 2] * 2 * np.pi / period) > 0
    b = np.sin(pos[:, 0] * 2 * np.pi / period) > 0
    truth = np.where((a ^ b)[:, None], RED, WHITE)
    seen = seen_front(th, 95)
    back = ~seen
    ends = back & (np.abs(pos[:, 2] - 1.25) > 0.15)  # where the centre plane is 9-15 cm off the middle
    agree = {}
    for column in (0.015, 0.0):
        cfg = WrapFillConfig(smooth_sweeps=0, mirror_column=column)
        out = wrap_fill_colors(pos, np.zeros(len(pos), int), seen, truth, None, cfg).numpy()
        agree[column] = [(np.linalg.norm(out[r] - truth[r], axis=1) < 1e-6).mean() for r in (back, ends)]
        np.testing.assert_allclose(out[seen], truth[seen].astype(np.float32), atol=1e-6)
    assert agree[0.015][0] > 0.98 and agree[0.015][1] > 0.98
    assert agree[0.0][1] < 0.8  # the same-height median there: 0.69


def test_column_middle_against_a_brute_force_reference():
    rng = np.random.default_rng(3)
    part = rng.uniform([-0.2, -0.15, 0.0], [0.2, 0.15, 0.6], (400, 3))
    query = rng.uniform([-0.25, -0.2, -0.05], [0.25, 0.2, 0.65], (300, 3))
    radius, fallback = 0.04, -0.03
    got = column_middle(part, query, radius, fallback)
    want = np.full(len(query), fallback)
    for i, q in enumerate(query):
        near = np.hypot(part[:, 0] - q[0], part[:, 2] - q[2]) <= radius
        if near.sum() >= 2:
            want[i] = 0.5 * (part[near, 1].min() + part[near, 1].max())
    assert (want == fallback).sum() > 5 and (want != fallback).sum() > 200  # both cases are exercised
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # the depth of the query does not matter, only its x and height
    shifted = query.copy()
    shifted[:, 1] += 1.0
    np.testing.assert_array_equal(column_middle(part, shifted, radius, fallback), got)
    assert column_middle(part[:1], query, radius, fallback).tolist() == [fallback] * len(query)


def test_no_mirror_regions_take_the_low_frequency_fill_only():
    # the checks' back is the front's mirror; a region marked no_mirror (a redo) gets the
    # same-height fill instead, everything else is as before
    pos, th = cylinder()
    a = np.sin(pos[:, 2] * 2 * np.pi / 0.1) > 0
    b = np.sin(pos[:, 0] * 2 * np.pi / 0.1) > 0
    truth = np.where((a ^ b)[:, None], RED, WHITE)
    seen = seen_front(th, 95)
    cfg = WrapFillConfig(smooth_sweeps=0)
    parts = np.zeros(len(pos), int)
    region = ~seen & (np.abs(pos[:, 0]) < 0.06) & (np.abs(pos[:, 2] - 1.25) < 0.1)
    with_mirror = wrap_fill_colors(pos, parts, seen, truth, None, cfg).numpy()
    out = wrap_fill_colors(pos, parts, seen, truth, None, cfg, no_mirror=region).numpy()
    no_mirror_cfg = WrapFillConfig(smooth_sweeps=0, no_mirror_parts=tuple(PART_INDEX))
    low_only = wrap_fill_colors(pos, parts, seen, truth, None, no_mirror_cfg).numpy()
    np.testing.assert_array_equal(out[~region], with_mirror[~region])
    np.testing.assert_array_equal(out[region], low_only[region])
    assert np.abs(out[region] - with_mirror[region]).max() > 0.3  # the mirror step did change the region


def test_head_back_is_hair_not_face():
    # a sphere-ish head: face in front (|theta| < 60 deg, below the hairline), hair elsewhere
    pos, th = cylinder(radius=0.09, height=0.22, n_theta=72, n_z=44, z0=1.55)
    face = (np.abs(np.degrees(th)) < 60) & (pos[:, 2] < 1.72)
    col = np.where(face[:, None], SKIN, HAIR)
    seen = seen_front(th, 100)
    parts = np.full(len(pos), PART_INDEX["head"])
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05


def test_head_back_is_hair_not_the_ears_at_the_same_height():
    # at face height the video saw the head only up to the ears (skin, in front of the coronal
    # plane); above, the hair round the sides up to 100 degrees. The back at face height takes the
    # hair seen behind the centre, not a band of ear-coloured skin across it
    pos, th = cylinder(radius=0.09, height=0.22, n_theta=72, n_z=44, z0=1.55)
    deg = np.abs(np.degrees(th))
    low = pos[:, 2] < 1.72
    skin = low & (deg < 92)
    col = np.where(skin[:, None], SKIN, HAIR)
    seen = np.where(low, deg < 92, deg <= 100)
    parts = np.full(len(pos), PART_INDEX["head"])
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05
    # without the rule (the band on both sides of the centre) the skin band comes back: the case is real
    both = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(posterior_band_parts=())).numpy()
    assert np.linalg.norm(both[back & low] - SKIN, axis=1).mean() < 0.05


def test_head_back_is_hair_where_the_posterior_band_shows_only_ear_skin():
    # a video that turned to 100 degrees: behind the centre it saw hair, except at ear height,
    # where the ears (and the skin behind them) fill the sides up to 100 degrees. The back at ear
    # height takes the hair above and below, not the ears' skin carried across it
    pos, th = cylinder(radius=0.09, height=0.22, n_theta=72, n_z=44, z0=1.55)
    deg = np.abs(np.degrees(th))
    face = (deg < 60) & (pos[:, 2] < 1.72)
    ears = (deg > 80) & (deg <= 100) & (np.abs(pos[:, 2] - 1.625) < 0.025)
    col = np.where((face | ears)[:, None], SKIN, HAIR)
    seen = deg <= 100
    parts = np.full(len(pos), PART_INDEX["head"])
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05
    # without the face's colour cluster (the hair rule standing down) the ears' skin is carried
    # round at their height: the case is real
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_min_share=1.1)).numpy()
    ear_back = back & (np.abs(pos[:, 2] - 1.625) < 0.015)
    assert np.linalg.norm(off[ear_back] - SKIN, axis=1).mean() < 0.05


def test_parts_are_filled_separately_and_returns_float32_tensor():
    pos, th = cylinder()
    torso_top = pos[:, 2] > 1.25
    parts = np.where(torso_top, PART_INDEX["torso"], PART_INDEX["thigh.L"])
    col = np.where(torso_top[:, None], RED, BLUE)
    seen = seen_front(th)
    out = wrap_fill_colors(torch.as_tensor(pos), parts, torch.as_tensor(seen), torch.as_tensor(col), None)
    assert out.dtype == torch.float32 and out.shape == (len(pos), 3)
    o = out.numpy()
    np.testing.assert_allclose(o[~seen & torso_top], np.tile(RED, ((~seen & torso_top).sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(o[~seen & ~torso_top], np.tile(BLUE, ((~seen & ~torso_top).sum(), 1)), atol=1e-6)


def test_nothing_seen_or_everything_seen():
    pos, th = cylinder(n_theta=16, n_z=8)
    col = np.random.default_rng(0).random((len(pos), 3))
    parts = np.zeros(len(pos), int)
    np.testing.assert_allclose(wrap_fill_colors(pos, parts, np.ones(len(pos), bool), col).numpy(), col, atol=1e-6)
    np.testing.assert_allclose(wrap_fill_colors(pos, parts, np.zeros(len(pos), bool), col).numpy(), col, atol=1e-6)


def test_grazing_seen_gaussians_are_repainted_except_on_the_head():
    from reconstruct.appearance.wrap_fill import reliable_seen

    pos, th = cylinder()
    normals = np.c_[np.sin(th), -np.cos(th), np.zeros_like(th)]
    seen = seen_front(th, 100)
    torso = np.full(len(pos), PART_INDEX["torso"])
    rel = reliable_seen(seen, normals, torso)
    deg = np.abs(np.degrees(th))
    # the mean seen normal is the front (-Y): seen beyond 70 degrees is not a colour source
    assert rel[seen & (deg < 65)].all() and not rel[seen & (deg > 75)].any()
    head = np.full(len(pos), PART_INDEX["head"])
    np.testing.assert_array_equal(reliable_seen(seen, normals, head), seen)
    # dark fringe colours (as Stage I learns them at the silhouette) do not reach the back
    col = np.tile(BLUE, (len(pos), 1))
    col[seen & (deg > 80)] *= 0.3
    out = wrap_fill_colors(pos, torso, seen, col, None, normals=normals).numpy()
    np.testing.assert_allclose(out[~seen], np.tile(BLUE, ((~seen).sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(out[seen & (deg > 80)], np.tile(BLUE, ((seen & (deg > 80)).sum(), 1)), atol=1e-6)


def test_stage2_config_propagation_choices():
    from reconstruct.stage2.config import Stage2Config

    assert Stage2Config().propagation == "wrap"
    Stage2Config(propagation="diffusion")
    with pytest.raises(ValueError, match="propagation"):
        Stage2Config(propagation="mirror")


# ---------------------------------------------------------------------------------------------
# a head seen from the front only (one photo): no seen Gaussian behind its centre


def front_only_head(skin_sides=True):
    """A head seen up to 80 degrees from the front: at face height the seen sides are skin (the
    cheeks reach the silhouette), hair above 1.70 m all round. Returns pos, theta, seen, truth."""
    pos, th = cylinder(radius=0.09, height=0.22, n_theta=72, n_z=44, z0=1.55)
    deg = np.abs(np.degrees(th)) - 1e-9  # both columns at +-80 degrees (+80 rounds up)
    seen = deg <= 80
    skin = (pos[:, 2] < 1.70) & (deg <= 80 if skin_sides else deg < 50)
    return pos, th, seen, np.where(skin[:, None], SKIN, HAIR)


def test_front_only_head_back_and_crown_take_the_hair():
    pos, th, seen, truth = front_only_head()
    parts = np.full(len(pos), PART_INDEX["head"])
    col = np.where(seen[:, None], truth, 0.5)
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05
    np.testing.assert_allclose(out[seen], col[seen].astype(np.float32), atol=1e-6)
    # without the hair rule the face's skin is carried round at face height: the case is real
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_min_share=1.1)).numpy()
    low_back = back & (pos[:, 2] < 1.68)
    assert np.linalg.norm(off[low_back] - SKIN, axis=1).mean() < 0.05


def test_front_only_head_with_a_few_seen_just_behind_its_centre_takes_the_hair():
    """A photo's head, bent and turned, shows a column of its silhouette's edge just behind its
    centre: skin at face height (the sweater photo: 9 band Gaussians there, 2 % of the head). More
    than ``k``, far under ``behind_share`` of the head's back: the head was never seen behind, and
    its back and crown take the hair the front shows, not the median of that column (skin)."""
    pos, th, seen, truth = front_only_head()
    edge = (np.abs(np.degrees(th) - 95) < 1) & (pos[:, 2] < 1.70)  # one column, at face height
    seen = seen | edge
    truth = np.where(edge[:, None], SKIN, truth)
    parts = np.full(len(pos), PART_INDEX["head"])
    behind = pos[:, 1] > pos[:, 1].mean()
    cfg = WrapFillConfig()
    assert cfg.k <= (edge & behind).sum() < cfg.behind_share * behind.sum()  # the case the rule is for
    col = np.where(seen[:, None], truth, 0.5)
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen & (np.abs(np.degrees(th)) > 120)
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05
    # read as a head seen behind its centre (its band there: the skin column), the back is skin
    seen_behind = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(behind_share=0.0)).numpy()
    assert np.linalg.norm(seen_behind[back & (pos[:, 2] < 1.68)] - SKIN, axis=1).mean() < 0.05


def test_front_only_head_that_tells_no_hair_keeps_its_posterior_band():
    """Where the front tells no hair from face (the green-jacket photo: the middle split 38 to 37
    between the two colours), a head never seen behind its centre keeps the posterior band it has
    -- here the hair of a column just behind the centre -- not the front's same-height colours: its
    cheeks' skin, which painted the lower back of the head skin-coloured."""
    pos, th, _, _ = front_only_head()
    deg = np.abs(np.degrees(th))
    edge = (np.abs(np.degrees(th) - 95) < 1) & (pos[:, 2] < 1.70)  # hair just behind the centre
    seen = (deg <= 85) | edge
    skin = (deg <= 85) & (pos[:, 2] < 1.70) & ~((deg < 30) & (pos[:, 0] < 0))  # a lock across the face
    truth = np.where(skin[:, None], SKIN, HAIR)
    parts = np.full(len(pos), PART_INDEX["head"])
    col = np.where(seen[:, None], truth, 0.5)
    cfg = WrapFillConfig()
    assert not hair_sources(pos[seen], col[seen], pos[:, 0].mean(), contrast=cfg.hair_contrast,
                            min_share=cfg.hair_min_share, k=cfg.k).any()
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen & (deg > 120)
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05


def test_front_only_heads_hair_runs_down_the_back_without_bands():
    """A photo's rim of hair changes from height to height (a lit strand, a shadowed one). Hair
    runs down, so the back of the head takes the median of all the hair within ``hair_slab`` of
    each height, both sides pooled: at most a gentle change down the back. With the ``k`` nearest
    at the same height (``hair_slab=0``) the strands' light and shade were drawn round the back
    as horizontal bands (the red-dress and group photos)."""
    pos, th, seen, truth = front_only_head(skin_sides=False)
    hair = np.all(truth == HAIR, axis=1)
    band = 0.5 * np.sin(pos[:, 2] * 2 * np.pi / 0.025)  # light and shade, 2.5 cm from strand to strand
    truth = np.where(hair[:, None], np.clip(HAIR + 0.3 * band[:, None], 0, 1), truth)
    parts = np.full(len(pos), PART_INDEX["head"])
    col = np.where(seen[:, None], truth, 0.5)
    back = ~seen & (np.abs(np.degrees(th)) > 120)
    z = np.unique(np.round(pos[back, 2], 6))

    def rows(out):  # the back's mean colour at each height
        return np.stack([out[back & (np.abs(pos[:, 2] - h) < 1e-6)].mean(0) for h in z])
    new = rows(wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0, front_only_median=0)).numpy())
    old = rows(wrap_fill_colors(pos, parts, seen, col, None,
                                WrapFillConfig(smooth_sweeps=0, front_only_median=0, hair_slab=0.0)).numpy())
    step = lambda r: np.abs(np.diff(r, axis=0)).max(1).mean()  # noqa: E731
    assert step(old) > 0.04  # the bands
    assert step(new) < 0.5 * step(old)  # 0.024 against 0.068
    assert np.abs(np.median(new, 0) - HAIR).max() < 0.08  # still the hair's colour


def test_front_only_heads_hair_where_the_rim_holds_few_strands_is_the_hair_round_it():
    """At ear height a photo's rim holds few hair Gaussians (the ears take the sides), and a lit
    strand among them drew a light line across the back of the grey-skirt photo's dark hair. The
    profile takes at least ``hair_profile_share`` of the hair Gaussians, the nearest in height:
    where the rim is sparse it reaches the hair above and below."""
    pos, th, seen, truth = front_only_head(skin_sides=False)
    deg = np.abs(np.degrees(th))
    lit = np.array([0.45, 0.3, 0.2])
    ears = (deg > 50) & (pos[:, 2] > 1.57) & (pos[:, 2] < 1.68)
    truth[ears] = SKIN
    few = ears & (deg > 70) & (deg < 80) & (np.round((pos[:, 2] - 1.55) / 0.22 * 43) % 3 == 0)
    truth[few] = lit  # a lit strand at a few heights between the ears' skin
    parts = np.full(len(pos), PART_INDEX["head"])
    col = np.where(seen[:, None], truth, 0.5)
    back = ~seen & (deg > 120) & (np.abs(pos[:, 2] - 1.625) < 0.006)
    cfg = WrapFillConfig(smooth_sweeps=0, front_only_median=0)
    new = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    old = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0, front_only_median=0,
                                                                      hair_profile_share=0.0)).numpy()
    assert few.sum() >= 8 and back.sum() > 20
    assert np.linalg.norm(old[back] - lit, axis=1).mean() < 0.1  # the line
    assert np.linalg.norm(new[back] - HAIR, axis=1).max() < 0.05


def test_height_profile_against_a_brute_force_reference():
    rng = np.random.default_rng(7)
    zs, cs = rng.uniform(0, 1, 300), rng.uniform(0, 1, (300, 3))
    zq = np.r_[rng.uniform(-0.2, 1.2, 200), 5.0]
    got = height_profile(zq, zs, cs, 0.05, 8)
    for i, z in enumerate(zq):
        near = np.abs(zs - z) <= 0.05
        if near.sum() < 8:
            near = np.zeros(300, bool)
            near[np.argsort(np.abs(zs - z))[:8]] = True
        np.testing.assert_allclose(got[i], np.median(cs[near], axis=0), atol=1e-12)
    assert np.isnan(height_profile(zq, zs[:0], cs[:0], 0.05, 8)).all()


def test_front_only_head_reads_its_hair_from_the_less_eroded_flags():
    """The hair framing a face in a photo is a ring the fill's erosion takes: with the trusted flags
    holding none of it the rule finds no hair and the back at face height takes the face's skin;
    given ``hair_seen`` (the flags eroded less), the hair is read there and the back is hair."""
    pos, th, seen, truth = front_only_head()
    parts = np.full(len(pos), PART_INDEX["head"])
    col = np.where(seen[:, None], truth, 0.5)
    trusted = seen & (pos[:, 2] < 1.70)  # the hair above the face eroded away
    low_back = ~seen & (pos[:, 2] < 1.68)
    without = wrap_fill_colors(pos, parts, trusted, col, None).numpy()
    assert np.linalg.norm(without[low_back] - SKIN, axis=1).mean() < 0.05
    with_ring = wrap_fill_colors(pos, parts, trusted, col, None, hair_seen=seen).numpy()
    assert np.linalg.norm(with_ring[low_back] - HAIR, axis=1).max() < 0.05
    # the trusted Gaussians keep their colours; the hair ring is filled like any untrusted one
    np.testing.assert_allclose(with_ring[trusted], col[trusted].astype(np.float32), atol=1e-6)


def test_a_turned_faces_far_cheek_takes_the_near_cheek_mirrored():
    """A photo of a face turned from the camera sees one cheek to the ear and the other not at
    all. Left to the band and the hair rule, the far cheek took the hair beside it (a black cheek
    from the side on five of seven photos); mirrored left-right through the head's midline it
    takes the near cheek's skin, and the far temple the near temple's hair."""
    pos, th, _, _ = front_only_head()
    deg = np.degrees(th)
    skin = (pos[:, 2] < 1.70) & (np.abs(deg) <= 70)
    truth = np.where(skin[:, None], SKIN, HAIR)
    # an eye on each side, 35-45 degrees out
    eye = (np.abs(np.abs(deg) - 40) < 6) & (np.abs(pos[:, 2] - 1.65) < 0.008)
    truth[eye] = HAIR
    seen = (deg >= -85) & (deg <= 30)
    parts = np.full(len(pos), PART_INDEX["head"])
    col = np.where(seen[:, None], truth, 0.5)
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    low = (pos[:, 2] > 1.57) & (pos[:, 2] < 1.67)
    # the far eye's middle is the near eye's colour: the front-only median leaves the mirror alone
    far_eye = eye & (np.abs(deg - 40) < 1) & (np.abs(pos[:, 2] - 1.65) < 0.003)
    assert far_eye.sum() >= 1
    assert np.linalg.norm(out[far_eye] - HAIR, axis=1).max() < 0.05
    low &= ~(np.abs(pos[:, 2] - 1.65) < 0.015)  # the cheek and temple below, away from the eyes
    cheek = ~seen & low & (deg > 38) & (deg < 62)
    temple = ~seen & low & (deg > 76) & (deg < 88)
    back = np.abs(deg) > 110
    assert cheek.sum() > 20 and temple.sum() > 10
    assert np.linalg.norm(out[cheek] - SKIN, axis=1).max() < 0.05
    assert np.linalg.norm(out[temple] - HAIR, axis=1).max() < 0.05
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05
    np.testing.assert_allclose(out[seen], col[seen].astype(np.float32), atol=1e-6)
    # without the mirror the far cheek takes the hair: the case is real
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(face_mirror_parts=())).numpy()
    assert np.linalg.norm(off[cheek] - HAIR, axis=1).mean() < 0.1


def test_left_right_mirror_reads_the_seen_side_in_front_only():
    """``_left_right_mirror`` against a direct reading: the median of the seen Gaussians within
    reach of the mirror image (x -> 2 cx - x), at least 2 of them; NaN behind the centre or with
    fewer than 2 in reach."""
    rng = np.random.default_rng(3)
    src = rng.uniform(-0.05, 0.05, (3000, 3)) + np.array([0.04, -0.02, 0.0])
    src_col = rng.uniform(0, 1, (3000, 3))
    todo = rng.uniform(-0.05, 0.05, (300, 3))
    cx, cy, reach = 0.01, 0.0, 0.006
    got = _left_right_mirror(todo, src, src_col, cx, cy, reach, k=4)
    for t, g in zip(todo, got):
        q = np.array([2 * cx - t[0], t[1], t[2]])
        d = np.linalg.norm(src - q, axis=1)
        near = np.argsort(d)[:4]
        near = near[d[near] <= reach]
        if t[1] >= cy or len(near) < 2:
            assert np.isnan(g).all()
        else:
            np.testing.assert_allclose(g, np.median(src_col[near], axis=0), atol=1e-12)
    assert np.isfinite(got[:, 0]).sum() > 30 and np.isnan(got[:, 0]).sum() > 30


def test_front_only_head_band_is_behind_the_centre_not_the_face_sides():
    # a bent head (the sweater photo): at face height the seen region stops at the cheeks, 35
    # degrees short of the sides, while the hair is seen round to the sides above. The unseen
    # strips beside the face are joined to the back of the head, but the head's band is read next
    # to its unseen Gaussians behind the centre only: the back takes the hair, not the cheeks' skin.
    # The hair rule stands down (as on that photo), so this is the band's doing
    pos, th, _, truth = front_only_head()
    deg = np.abs(np.degrees(th))
    seen = np.where(pos[:, 2] < 1.70, deg <= 55, deg <= 80)
    parts = np.full(len(pos), PART_INDEX["head"])
    col = np.where(seen[:, None], truth, 0.5)
    cfg = WrapFillConfig(smooth_sweeps=0, front_only_median=0, hair_min_share=1.1)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    back = ~seen & (deg > 100)
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05


def test_front_only_head_hat_over_hair_keeps_its_heights():
    pos, th, seen, truth = front_only_head()
    hat = pos[:, 2] > 1.74
    truth[hat] = RED
    parts = np.full(len(pos), PART_INDEX["head"])
    # the hair rule alone (no smoothing of either kind)
    out = wrap_fill_colors(pos, parts, seen, truth, None, WrapFillConfig(smooth_sweeps=0, front_only_median=0)).numpy()
    back = ~seen
    np.testing.assert_allclose(out[back & (pos[:, 2] > 1.75)], np.tile(RED, ((back & (pos[:, 2] > 1.75)).sum(), 1)),
                               atol=1e-6)
    np.testing.assert_allclose(out[back & (pos[:, 2] < 1.73)], np.tile(HAIR, ((back & (pos[:, 2] < 1.73)).sum(), 1)),
                               atol=1e-6)


def test_front_only_bald_head_with_glasses_and_lips_stays_skin():
    # no hair to take: the rule stands down (glasses reaching the temples and the lips are too few
    # to be hair) and the fill is exactly the one without the rule
    pos, th, seen, _ = front_only_head()
    deg = np.abs(np.degrees(th))
    col = np.tile(SKIN, (len(pos), 1))
    col[(np.abs(pos[:, 2] - 1.66) < 0.006) & (deg < 70)] = HAIR  # the glasses' frame and temples
    col[(np.abs(pos[:, 2] - 1.60) < 0.006) & (deg < 15)] = RED  # the lips
    parts = np.full(len(pos), PART_INDEX["head"])
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_min_share=1.1)).numpy()
    np.testing.assert_array_equal(out, off)


def test_hair_as_light_as_the_skin_is_no_hair():
    pos, th, seen, truth = front_only_head()
    light = np.where(np.all(truth == HAIR, axis=1)[:, None], SKIN - 0.1, SKIN)  # within the contrast
    src = np.flatnonzero(seen)
    assert not hair_sources(pos[src], light[src], 0.0, contrast=0.15, min_share=0.1, k=8).any()
    found = hair_sources(pos[src], truth[src], 0.0, contrast=0.15, min_share=0.1, k=8)
    # the hair found is hair, and it is the rim of the seen head: all of the hair above the face
    assert np.all(truth[src][found] == HAIR) and found.sum() == np.all(truth[src] == HAIR, axis=1).sum()


def test_front_only_head_with_hair_across_the_face_stands_down():
    # hair falling over the face in strands: the middle is split between two colours and tells no
    # face from hair; the fill is the one without the rule
    pos, th, seen, truth = front_only_head()
    deg = np.degrees(th)
    strands = (pos[:, 2] < 1.70) & (np.abs(deg) < 80) & (np.floor(deg / 10) % 2 == 0)
    col = truth.copy()
    col[strands] = HAIR
    parts = np.full(len(pos), PART_INDEX["head"])
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_min_share=1.1)).numpy()
    np.testing.assert_array_equal(out, off)
    # with fewer strands (a fringe at one side) the face holds the middle and the rule runs
    col = truth.copy()
    col[strands & (deg > 40)] = HAIR
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_min_share=1.1)).numpy()
    assert np.abs(out - off).max() > 0.3


# ---------------------------------------------------------------------------------------------
# parts never seen behind their centre: their backs are smoothed more (front_only_median)


def cylinder_neighbours(n_theta, n_z):
    """(N,4) grid neighbours of ``cylinder``'s points: round the ring (wrapping) and up/down."""
    idx = np.arange(n_theta * n_z).reshape(n_z, n_theta)
    nb = np.full((n_z, n_theta, 4), -1)
    nb[..., 0] = np.roll(idx, -1, 1)
    nb[:-1, :, 1] = idx[1:]
    nb[..., 2] = np.roll(idx, 1, 1)
    nb[1:, :, 3] = idx[:-1]
    return nb.reshape(-1, 4)


def _shaded_torso():
    """A torso (72 x 60 cylinder) of one cloth colour under uneven light -- a shade per row: folds
    and light -- with its grid neighbours and each point's angle from the front in degrees:
    (pos, col, parts, nb, deg)."""
    pos, th = cylinder(n_theta=72, n_z=60)
    rng = np.random.default_rng(0)
    shade = rng.uniform(-0.15, 0.15, 60).repeat(72)
    col = np.clip(np.tile([0.35, 0.4, 0.3], (len(pos), 1)) + shade[:, None], 0, 1)
    return pos, col, np.full(len(pos), PART_INDEX["torso"]), cylinder_neighbours(72, 60), np.abs(np.degrees(th))


def _seen_to_the_shoulders(deg):
    """(top, seen): the top 6 rows of ``_shaded_torso``, and the torso seen to 80 degrees with those
    rows (the shoulders of a photo) seen to 100."""
    top = np.arange(len(deg)) >= 54 * 72
    return top, (deg <= 80) | (top & (deg <= 100))


def test_front_only_part_back_is_smoothed_and_a_part_seen_behind_is_not():
    # a torso seen from the front only (to 80 degrees) under uneven light: the sides' colours
    # vary from row to row. The back is smoother with the front-only sweeps; the same torso seen
    # to 100 degrees (behind its centre) is filled exactly as without them
    pos, col, parts, nb, deg = _shaded_torso()
    for seen, front_only in ((deg <= 80, True), (deg <= 100, False)):
        out = wrap_fill_colors(pos, parts, seen, col, nb).numpy()
        off = wrap_fill_colors(pos, parts, seen, col, nb, WrapFillConfig(front_only_median=0)).numpy()
        back = deg > 150
        if front_only:
            # row-to-row differences down the back's middle shrink
            rough = lambda c: np.abs(np.diff(c[back].reshape(60, -1).mean(1))).mean()  # noqa: E731
            assert rough(out) < 0.5 * rough(off)
            np.testing.assert_allclose(out[seen], col[seen].astype(np.float32), atol=1e-6)
        else:
            np.testing.assert_array_equal(out, off)


def test_a_few_seen_gaussians_just_behind_the_centre_leave_a_part_front_only():
    # the shaded torso seen to 80 degrees, and its top rows (the shoulders of a photo) to 100: 24
    # seen Gaussians behind its centre, more than k, 1 % of those behind it. Still a front-only
    # part: its back is smoothed as the plain 80-degree torso's is; counted by k alone it was not
    pos, col, parts, nb, deg = _shaded_torso()
    _, seen = _seen_to_the_shoulders(deg)
    assert ((deg > 90) & seen).sum() == 24
    back = deg > 150
    rough = lambda c: np.abs(np.diff(c[back].reshape(60, -1).mean(1))).mean()  # noqa: E731
    out = wrap_fill_colors(pos, parts, seen, col, nb).numpy()
    unsmoothed = wrap_fill_colors(pos, parts, seen, col, nb, WrapFillConfig(front_only_median=0)).numpy()
    by_k_alone = wrap_fill_colors(pos, parts, seen, col, nb, WrapFillConfig(behind_share=0.0)).numpy()
    assert rough(out) < 0.5 * rough(unsmoothed)
    np.testing.assert_array_equal(by_k_alone, unsmoothed)
    # seen to 100 degrees all the way up (11 % of those behind the centre) it is seen behind
    seen_all = deg <= 100
    np.testing.assert_array_equal(wrap_fill_colors(pos, parts, seen_all, col, nb).numpy(),
                                  wrap_fill_colors(pos, parts, seen_all, col, nb,
                                                   WrapFillConfig(front_only_median=0)).numpy())


def test_a_front_seen_behind_the_centre_plane_is_no_view_of_the_back():
    # the shaded torso seen to 80 degrees, its top 12 rows set back by 16 cm (the shoulders and the
    # upper chest of a torso whose belly lies in front): their seen Gaussians still face the
    # front, but 228 lie behind the part's mean depth, 10 % of those behind it. By position
    # alone that is a view of the back, and the back is filled unsmoothed; given the surface
    # normals (+Y is the back) they are no view of it, and the part is front-only
    pos, col, parts, nb, deg = _shaded_torso()
    th = np.radians(deg) * np.sign(pos[:, 0])
    normals = np.c_[np.sin(th), -np.cos(th), np.zeros(len(pos))]
    top = np.arange(len(pos)) >= 48 * 72
    pos = pos + np.c_[np.zeros(len(pos)), 0.16 * top, np.zeros(len(pos))]
    seen = deg <= 80
    centre_y = pos[:, 1].mean()
    assert ((pos[:, 1] > centre_y) & seen).sum() == 228 and not ((normals[:, 1] > 0) & seen).any()
    back = deg > 150
    rough = lambda c: np.abs(np.diff(c[back].reshape(60, -1).mean(1))).mean()  # noqa: E731
    out = wrap_fill_colors(pos, parts, seen, col, nb, surface_normals=normals).numpy()
    by_position = wrap_fill_colors(pos, parts, seen, col, nb).numpy()
    unsmoothed = wrap_fill_colors(pos, parts, seen, col, nb, WrapFillConfig(front_only_median=0),
                                  surface_normals=normals).numpy()
    np.testing.assert_array_equal(by_position, wrap_fill_colors(pos, parts, seen, col, nb,
                                                                WrapFillConfig(front_only_median=0)).numpy())
    assert rough(out) < 0.5 * rough(unsmoothed)
    with pytest.raises(ValueError, match="surface_normals must have shape"):
        wrap_fill_colors(pos, parts, seen, col, nb, surface_normals=normals[:-1])
    # the back seen (to 120 degrees, facing back there) counts with the normals too
    seen_all = deg <= 120
    np.testing.assert_array_equal(
        wrap_fill_colors(pos, parts, seen_all, col, nb, surface_normals=normals).numpy(),
        wrap_fill_colors(pos, parts, seen_all, col, nb, WrapFillConfig(front_only_median=0),
                         surface_normals=normals).numpy())


def test_seen_behind_is_counted_on_what_a_garment_layer_leaves_visible():
    # the same torso, its lower 54 rows under a coat's layer (``under_layer``: here each points at
    # itself, so the final copy from the cloth changes nothing): the 24 seen behind its centre are
    # 11 % of the 216 behind it a camera could see, so the part is seen behind (no front-only
    # smoothing); counted on all 2,160 behind it (1 %) it was front-only, and a walk's coat took
    # the front's buttons over its upper back
    pos, col, parts, nb, deg = _shaded_torso()
    top, seen = _seen_to_the_shoulders(deg)
    under = np.where(top, -1, np.arange(len(pos)))
    out = wrap_fill_colors(pos, parts, seen, col, nb, under_layer=under).numpy()
    unsmoothed = wrap_fill_colors(pos, parts, seen, col, nb, WrapFillConfig(front_only_median=0),
                                  under_layer=under).numpy()
    np.testing.assert_array_equal(out, unsmoothed)
    everywhere = wrap_fill_colors(pos, parts, seen, col, nb, under_layer=np.full(len(pos), -1)).numpy()
    assert not np.array_equal(everywhere, wrap_fill_colors(pos, parts, seen, col, nb, WrapFillConfig(front_only_median=0),
                                                           under_layer=np.full(len(pos), -1)).numpy())


def _coat_torso():
    """A coat's torso (a tube, its sides from 60 to 110 degrees missing: the shoulders' sides
    stretched and eroded, no seen surface within ``band`` of its upper back): its lower part under
    the layer's cloth (unseen; each takes the colour of ``cloth``, a stand-in for the layer
    Gaussian over it), a seen patch low on its back under the cloth's gap (so it is seen behind
    its centre), its upper chest seen with red and white stripes by height and a front-only green
    trim along the layer's top. The band is the trim row and the patch's edge: the upper back's
    heights lie more than ``band_reach`` from both."""
    GREEN = np.array([0.3, 0.8, 0.4])
    pos, th = cylinder()
    deg = np.abs(np.degrees(th))
    keep = (deg <= 60) | (deg >= 110)
    pos, deg = pos[keep], deg[keep]
    z = pos[:, 2]
    truth = np.where(stripes(z, 0.04)[:, None] > 0, WHITE, RED)
    col = truth.copy()
    col[(deg <= 60) & (z >= 1.3) & (z < 1.33)] = GREEN
    patch = (deg >= 150) & (z < 1.1)
    seen = ((deg <= 60) & (z >= 1.3)) | patch
    cloth = int(np.flatnonzero(patch)[0])
    under = np.where((z < 1.3) & ~patch, cloth, -1)
    parts = np.full(len(pos), PART_INDEX["torso"])
    return pos, deg, z, truth, col, seen, under, cloth, parts, GREEN


def test_heights_the_band_does_not_reach_take_the_seen_part_at_their_height():
    """With ``band_reach`` the upper back takes the seen chest's stripes of its height; without
    it, the slab widened to the trim's height painted the trim's green all over."""
    pos, deg, z, truth, col, seen, under, cloth, parts, GREEN = _coat_torso()
    back = (deg >= 110) & (z >= 1.38)
    phase = (z % 0.04) / 0.04
    interior = back & ((np.abs(phase - 0.25) < 0.15) | (np.abs(phase - 0.75) < 0.15))
    out = {reach: wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0, band_reach=reach),
                                   under_layer=under).numpy() for reach in (0.04, 0.0)}
    assert np.abs(out[0.04][interior] - truth[interior]).max() < 1e-6
    assert (np.abs(out[0.0][interior] - GREEN).max(1) < 1e-6).mean() > 0.9  # the trim carried round
    for o in out.values():
        np.testing.assert_allclose(o[seen], col[seen].astype(np.float32), atol=1e-6)
        hidden = under >= 0
        np.testing.assert_allclose(o[hidden], np.broadcast_to(o[cloth], (int(hidden.sum()), 3)), atol=1e-6)


def test_heights_the_band_does_not_reach_leave_out_the_necklines_skin():
    """The same torso with a deep neckline: the seen chest above 1.44 m is skin, the hands' colour.
    A back closes higher than a front, so the upper back does not take that skin (it takes the
    stripes seen within ``band_reach`` below, or the band's green); with no hands to tell the
    skin, it does."""
    pos, deg, z, truth, col, seen, under, cloth, parts, GREEN = _coat_torso()
    neckline = (deg <= 60) & (z >= 1.44)
    col[neckline] = SKIN
    hand = np.c_[np.linspace(0.5, 0.6, 40), np.zeros(40), np.full(40, 1.0)]  # a seen hand, away from the torso
    pos, col = np.r_[pos, hand], np.r_[col, np.broadcast_to(SKIN, (40, 3))]
    seen, under = np.r_[seen, np.ones(40, bool)], np.r_[under, np.full(40, -1)]
    parts = np.r_[parts, np.full(40, PART_INDEX["hand.L"])]
    top_back = np.r_[(deg >= 110) & (z >= 1.46), np.zeros(40, bool)]
    out = {hands: wrap_fill_colors(pos, parts, seen, col, None,
                                   WrapFillConfig(smooth_sweeps=0, hair_skin_from_hands=hands), under_layer=under).numpy()
           for hands in (True, False)}
    assert np.abs(out[True][top_back] - SKIN).max(1).min() > 0.3
    assert (np.abs(out[False][top_back] - SKIN).max(1) < 1e-6).mean() > 0.9


def test_heights_the_band_does_not_reach_leave_out_the_collars_edge():
    """The same torso with a neck over its front's top: the seen chest's top rows, within
    ``band`` of the neck, are the collar's edge (yellow here). The upper back at their heights does not take it; with the
    neck's Gaussians given another part (no neck to measure from) it does."""
    pos, deg, z, truth, col, seen, under, cloth, parts, GREEN = _coat_torso()
    edge = (deg <= 60) & (z >= 1.485)
    neck = pos[edge & (z >= 1.495)] + [0.0, 0.0, 0.01]  # a stand-in for the neck, over the front's top
    col[edge] = YELLOW
    n = len(neck)
    pos, col = np.r_[pos, neck], np.r_[col, np.broadcast_to(SKIN, (n, 3))]
    seen, under = np.r_[seen, np.ones(n, bool)], np.r_[under, np.full(n, -1)]
    top_back = np.r_[(deg >= 110) & (z >= 1.49), np.zeros(n, bool)]
    assert (np.linalg.norm(pos[:-n][edge][:, None] - neck[None], axis=2).min(1) <= WrapFillConfig().band).all()
    out = {}
    for part in ("neck", "head"):
        p = np.r_[parts, np.full(n, PART_INDEX[part])]
        out[part] = wrap_fill_colors(pos, p, seen, col, None, WrapFillConfig(smooth_sweeps=0), under_layer=under).numpy()
    assert np.abs(out["neck"][top_back] - YELLOW).max(1).min() > 0.3
    assert (np.abs(out["head"][top_back] - YELLOW).max(1) < 1e-6).mean() > 0.9


def test_part_with_nothing_seen_takes_the_nearest_filled_colours():
    # a neck the collar and the hair hid (no seen Gaussian): its back takes the filled hair of the
    # back of the head just above it, not the seen ear skin at the head's sides
    pos_h, th_h = cylinder(radius=0.09, height=0.22, n_theta=72, n_z=44, z0=1.55)
    deg_h = np.abs(np.degrees(th_h))
    face = (deg_h < 60) & (pos_h[:, 2] < 1.72)
    ears = (deg_h > 80) & (deg_h <= 100) & (pos_h[:, 2] < 1.60)
    col_h = np.where((face | ears)[:, None], SKIN, HAIR)
    pos_n, th_n = cylinder(radius=0.06, height=0.08, n_theta=48, n_z=16, z0=1.46)
    pos = np.r_[pos_h, pos_n]
    parts = np.r_[np.full(len(pos_h), PART_INDEX["head"]), np.full(len(pos_n), PART_INDEX["neck"])]
    seen = np.r_[deg_h <= 100, np.zeros(len(pos_n), bool)]
    col = np.r_[col_h, np.full((len(pos_n), 3), 0.5)]
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    neck_back = np.r_[np.zeros(len(pos_h), bool), np.abs(np.degrees(th_n)) > 150]
    assert np.linalg.norm(out[neck_back] - HAIR, axis=1).max() < 0.05
    # the nearest *seen* Gaussians are the ears' skin: the case is real
    from scipy.spatial import cKDTree
    _, j = cKDTree(pos[seen]).query(pos[neck_back])
    assert np.linalg.norm(col[seen][j] - SKIN, axis=1).mean() < 0.05


def test_front_only_part_band_is_the_sides_not_a_speckled_front():
    # a flat torso (a photo of a man in an open jacket) seen from the front only: a shirt down the
    # middle of the front, the jacket's green at the sides and all round the back. First hits on a
    # photo are speckled: a few of the front's Gaussians are unseen, so the shirt lies next to
    # unseen Gaussians too. The band that continues round the back is the sides next to the unseen
    # back, and the back is green -- a band read next to any unseen Gaussian took the shirt, the
    # nearest seen colour to the back's middle of a flat torso
    th, z = np.meshgrid(np.linspace(-np.pi, np.pi, 96, endpoint=False), np.linspace(1.0, 1.5, 60))
    th, z = th.ravel(), z.ravel()
    pos = np.c_[0.16 * np.sin(th), -0.05 * np.cos(th), z]
    green = np.array([0.1, 0.35, 0.3])
    shirt = np.abs(pos[:, 0]) < 0.06
    front = np.abs(np.degrees(th)) <= 80
    col = np.where((shirt & front)[:, None], WHITE, green)
    rng = np.random.default_rng(3)
    seen = front & (rng.random(len(pos)) > 0.1)
    parts = np.full(len(pos), PART_INDEX["torso"])
    cfg = WrapFillConfig(front_only_median=0, smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    back = np.abs(np.degrees(th)) > 120
    assert np.abs(out[back] - green).max() < 1e-6


def test_front_only_part_band_is_the_whole_seen_edge_across_a_gap():
    # a skirt seen from the front only, its seen region stopping 25 degrees short of the sides on
    # every row but three near the top, where a sleeve hanging beside it reaches round to the
    # side plane. The band is the seen edge that faces the unseen back all along it: the back is
    # the skirt's blue below the sleeve. Read only within 3 cm of the unseen Gaussians behind the
    # centre, the band was the sleeve alone, and it painted the whole back white
    th, z = np.meshgrid(np.linspace(-np.pi, np.pi, 96, endpoint=False), np.linspace(0.5, 1.0, 50))
    th, z = th.ravel(), z.ravel()
    ad = np.abs(np.degrees(th))
    pos = np.c_[0.15 * np.sin(th), -0.15 * np.cos(th), z]
    blue = np.array([0.1, 0.15, 0.45])
    sleeve = (z > 0.95) & (np.degrees(th) > 60) & (np.degrees(th) < 88)
    col = np.where(sleeve[:, None], WHITE, blue)
    seen = (ad <= 65) | sleeve
    parts = np.full(len(pos), PART_INDEX["torso"])
    cfg = WrapFillConfig(front_only_median=0, smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    back = (ad > 120) & (z < 0.9)
    assert np.abs(out[back] - blue).max() < 1e-6


def _torso_and_neck(front_deg: float):
    """A torso (a tube, 0.17 x 0.10 m, 1.0-1.5 m high, with a closed top over the shoulders) and a
    neck above it; the torso seen from the front only, to ``front_deg`` either side, the top and
    the neck unseen (the shoulders' tops are seen at grazing incidence)."""
    th, z = np.meshgrid(np.linspace(-np.pi, np.pi, 96, endpoint=False), np.linspace(1.0, 1.5, 51))
    th, z = th.ravel(), z.ravel()
    tube = np.c_[0.17 * np.sin(th), -0.10 * np.cos(th), z]
    gx, gy = np.meshgrid(np.linspace(-0.17, 0.17, 35), np.linspace(-0.10, 0.10, 21))
    inside = (gx / 0.17) ** 2 + (gy / 0.10) ** 2 < 0.9
    top = np.c_[gx[inside], gy[inside], np.full(inside.sum(), 1.5)]
    nth, nz = np.meshgrid(np.linspace(-np.pi, np.pi, 32, endpoint=False), np.linspace(1.51, 1.6, 10))
    neck = np.c_[0.05 * np.sin(nth.ravel()), -0.05 * np.cos(nth.ravel()), nz.ravel()]
    pos = np.r_[tube, top, neck]
    parts = np.r_[np.full(len(tube) + len(top), PART_INDEX["torso"]), np.full(len(neck), PART_INDEX["neck"])]
    seen = np.r_[np.abs(np.degrees(th)) <= front_deg, np.zeros(len(top) + len(neck), bool)]
    return pos, parts, seen, len(tube)


def _upper_back_with_and_without_the_rule(pos, parts, seen, col, n_tube):
    """The filled colours of the torso's upper back (behind, above 1.42 m) with the neckline rule
    and without it (``neckline_parts=()``); no smoothing of either kind."""
    upper_back = np.zeros(len(pos), bool)
    upper_back[:n_tube] = (pos[:n_tube, 1] > 0.05) & (pos[:n_tube, 2] > 1.42)
    return tuple(wrap_fill_colors(pos, parts, seen, col, None,
                                  WrapFillConfig(front_only_median=0, smooth_sweeps=0, **kw)).numpy()[upper_back]
                 for kw in ({}, {"neckline_parts": ()}))


def test_front_only_torso_band_leaves_out_the_neckline():
    # a dress with a wide neckline seen from the front only: the front's top rows are skin. The
    # band runs over the torso's top too, and carried round at its height the neckline's skin
    # painted the upper back (the red-dress photo). Within neckline_reach of the neck the band is
    # left out, and the upper back takes the dress's red of the sides below
    pos, parts, seen, n_tube = _torso_and_neck(70)
    col = np.tile(RED, (len(pos), 1))
    col[:n_tube][pos[:n_tube, 2] > 1.42] = SKIN
    out, old = _upper_back_with_and_without_the_rule(pos, parts, seen, col, n_tube)
    assert np.abs(out - RED).max() < 1e-6
    assert np.abs(old - SKIN).max(1).mean() < 0.05  # the case is real


def test_front_only_torso_band_judges_both_sides_without_the_neckline():
    # hair over one side of a dress's chest, lit near the skin's colour (the red-dress photo: the
    # lit blonde strands are not in the hair's palette), and the skin of the open collar on the
    # other side, by the neck. Compared round the sides before the neckline was left out, the lit
    # strands matched the collar's skin and stayed in the band when the skin went: the upper back
    # on the strands' side took them, a light blotch. Judged on the band without the neckline,
    # they are on one side only, and the back is the dress's red
    pos, parts, seen, n_tube = _torso_and_neck(40)
    deg = np.degrees(np.arctan2(pos[:, 0], -pos[:, 1]))
    z = pos[:, 2]
    tube = np.arange(len(pos)) < n_tube
    col = np.tile(RED, (len(pos), 1))
    col[tube & (deg > 5) & (z > 1.38)] = SKIN  # the collar open on one side, within neckline_reach
    lit = SKIN + np.array([0.05, 0.08, 0.0])
    col[tube & (deg < -5) & (z > 1.2) & (z < 1.34)] = lit  # strands past neckline_reach
    back = tube & (pos[:, 1] > 0.05) & (z > 1.2) & (z < 1.34)
    out = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(front_only_median=0, smooth_sweeps=0)).numpy()
    assert np.abs(out[back] - RED).max() < 1e-6
    # the case is real: with the collar's skin read as a colour of the cloth, the strands pass
    with_neck = wrap_fill_colors(pos, parts, seen, col, None,
                                 WrapFillConfig(front_only_median=0, smooth_sweeps=0, neckline_parts=())).numpy()
    assert (np.abs(with_neck[back] - RED).max(1) > 0.1).mean() > 0.2


def test_front_only_torso_with_only_a_neckline_band_takes_its_neighbours():
    # an open jacket's torso, a photo: the jacket (its own layer and sleeves) hides the torso but
    # for the shirt between its lapels, next to the neck. All of the torso's band lies within
    # neckline_reach of the neck; the torso is left to the fallback, and its back takes the
    # nearest colours of its neighbours (the sleeves), not the shirt's white
    green = np.array([0.1, 0.35, 0.3])
    pos, parts, seen, n_tube = _torso_and_neck(60)
    col = np.tile(WHITE, (len(pos), 1))
    seen[:n_tube] &= pos[:n_tube, 2] > 1.42
    th, r = np.meshgrid(np.linspace(-np.pi, np.pi, 24, endpoint=False), np.linspace(1.42, 1.5, 5))
    sleeves = [np.c_[sx * (0.2 + np.zeros(th.size)), 0.04 * np.cos(th.ravel()), r.ravel()] for sx in (-1, 1)]
    pos = np.r_[pos, sleeves[0], sleeves[1]]
    parts = np.r_[parts, np.full(th.size, PART_INDEX["upperarm.R"]), np.full(th.size, PART_INDEX["upperarm.L"])]
    col = np.r_[col, np.tile(green, (2 * th.size, 1))]
    seen = np.r_[seen, np.ones(2 * th.size, bool)]
    out, old = _upper_back_with_and_without_the_rule(pos, parts, seen, col, n_tube)
    assert np.abs(out - green).max() < 1e-6
    assert np.abs(old - WHITE).max(1).mean() < 0.05  # the case is real
    # a few of the shirt seen lower down, past neckline_reach (the cut-coat photo: 19 of a band of
    # 452, the layer and the folded arms hiding the rest): fewer than 4 k do not resolve the sides
    # either, and the back still takes the neighbours' green; a strip of 4 k or more is the torso's
    # own band, and its back takes the shirt's white
    deg = np.abs(np.degrees(np.arctan2(pos[:, 0], -pos[:, 1])))
    for rows, width, want in (((1.295, 1.325), 12.0, green), ((1.20, 1.30), 16.0, WHITE)):
        lower = seen.copy()
        lower[:n_tube] |= (pos[:n_tube, 2] > rows[0]) & (pos[:n_tube, 2] < rows[1]) & (deg[:n_tube] < width)
        n = int((lower & ~seen).sum())
        k = WrapFillConfig().k
        assert (k <= n < 4 * k) if want is green else n >= 4 * k, n
        got, _ = _upper_back_with_and_without_the_rule(pos, parts, lower, col, n_tube)
        assert np.abs(got - want).max() < 1e-6


def test_front_only_head_with_glasses_and_brows_takes_the_hair(monkeypatch):
    # big dark-rimmed glasses and brows: thin dark features over 29 % of the middle of the face,
    # so the face's colour cluster holds under FACE_SHARE of it counting every Gaussian. Only
    # Gaussians inside a region of their colour vote: the frames do not, and the back of the head
    # takes the hair (not the face's skin carried round)
    from reconstruct.appearance import hair
    pos, th, seen, truth = front_only_head()
    z, ad = pos[:, 2], np.abs(np.degrees(th))
    frame = ((((np.abs(z - 1.63) < 0.003) | (np.abs(z - 1.675) < 0.003)) & (ad <= 40))
             | ((z > 1.625) & (z < 1.68) & (np.abs(ad - 40) < 3)) | ((np.abs(z - 1.655) < 0.003) & (ad < 8)))
    brows = (np.abs(z - 1.69) < 0.003) & (ad > 5) & (ad < 35)
    col = np.where(seen[:, None], truth, 0.5)
    col[(frame | brows) & seen] = HAIR
    parts = np.full(len(pos), PART_INDEX["head"])
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    back = ~seen & (pos[:, 2] < 1.68)
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05
    # every Gaussian voting, the rule stands down and the back is skin: the case is real
    monkeypatch.setattr(hair, "CORE_AGREE", 0.0)
    off = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    assert np.linalg.norm(off[back] - SKIN, axis=1).mean() < 0.1


def test_front_only_head_whose_middle_is_mostly_hair_takes_the_face_from_the_hands():
    # hair across two thirds of the face in strands (the red-dress photo: a laughing woman, her
    # head bent, the crown and the hair over her cheeks seen, the face dotted): the middle's core
    # votes for the hair's colour, and without a reference the back of the head is the face's skin.
    # The seen hands show her skin: the cluster nearer to them is the face, and the back is hair
    pos, th, seen, truth = front_only_head()
    deg = np.degrees(th)
    strands = (pos[:, 2] < 1.70) & (np.abs(deg) < 80) & (np.floor(deg / 10) % 3 != 0)
    col = np.where(seen[:, None], truth, 0.5)
    col[strands] = HAIR
    hand_pos = np.random.default_rng(1).normal([0.3, 0.0, 1.0], 0.02, (64, 3))
    pos = np.r_[pos, hand_pos]
    col = np.r_[col, np.tile(SKIN * 0.9, (64, 1))]  # the hands a little shadowed
    seen = np.r_[seen, np.ones(64, bool)]
    parts = np.r_[np.full(len(th), PART_INDEX["head"]), np.full(64, PART_INDEX["hand.R"])]
    back = np.r_[~seen[:len(th)] & (pos[:len(th), 2] < 1.68), np.zeros(64, bool)]
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    assert np.linalg.norm(out[back] - HAIR, axis=1).max() < 0.05
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_skin_from_hands=False)).numpy()
    assert np.linalg.norm(off[back] - SKIN, axis=1).mean() < 0.1  # the case is real
    # hands in black gloves tell nothing: the vote decides, as without them
    gloved = col.copy()
    gloved[len(th):] = 0.05
    head = parts == PART_INDEX["head"]
    np.testing.assert_array_equal(wrap_fill_colors(pos, parts, seen, gloved, None).numpy()[head], off[head])


def _head_and_hands(left_colour, right_seen=5):
    """The front-only head (a face of SKIN, hair) and two hands (small tubes at x = +-0.3 m): the
    left's front half seen in ``left_colour``, the right with only ``right_seen`` seen Gaussians,
    in the same colour (a hand a photo hid, whose fitted few texels drew a coat)."""
    pos, th, seen, truth = front_only_head()
    col = np.where(seen[:, None], truth, 0.5)
    parts = [np.full(len(pos), PART_INDEX["head"])]
    P, C, S = [pos], [col], [seen]
    for x, name in ((0.3, "hand.L"), (-0.3, "hand.R")):
        hp, hth = cylinder(radius=0.03, height=0.08, n_theta=24, n_z=12, z0=1.0)
        hs = np.abs(np.degrees(hth)) <= 80 if name == "hand.L" else np.arange(len(hp)) < right_seen
        P.append(hp + [x, 0.0, 0.0])
        C.append(np.where(hs[:, None], left_colour, 0.5))
        S.append(hs)
        parts.append(np.full(len(hp), PART_INDEX[name]))
    return np.concatenate(P), np.concatenate(parts), np.concatenate(S), np.concatenate(C)


def test_a_hand_the_photo_hid_takes_the_faces_skin_not_its_twins_coat():
    """The right hand has 5 seen Gaussians and borrows the left's, all a coat's green: its unseen
    ones take the face's skin (the head's face cluster); with the rule off, its twin's green. A
    seen left hand of skin is borrowed as before; with no face the rule has nothing to give."""
    coat = np.array([0.38, 0.40, 0.32])
    pos, parts, seen, col = _head_and_hands(coat)
    right = (parts == PART_INDEX["hand.R"]) & ~seen
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    assert np.abs(out[right] - SKIN).max() < 1e-6
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hidden_hand_parts=())).numpy()
    assert np.abs(off[right] - coat).max(1).mean() < 0.05  # the case is real
    np.testing.assert_array_equal(out[parts != PART_INDEX["hand.R"]], off[parts != PART_INDEX["hand.R"]])
    pos, parts, seen, col = _head_and_hands(SKIN * 0.9)
    np.testing.assert_array_equal(wrap_fill_colors(pos, parts, seen, col, None).numpy(),
                                  wrap_fill_colors(pos, parts, seen, col, None,
                                                   WrapFillConfig(hidden_hand_parts=())).numpy())
    pos, parts, seen, col = _head_and_hands(coat)
    no_face = WrapFillConfig(hair_min_share=1.1)  # the hair rule stands down: no face cluster
    np.testing.assert_array_equal(wrap_fill_colors(pos, parts, seen, col, None, no_face).numpy(),
                                  wrap_fill_colors(pos, parts, seen, col, None,
                                                   dataclasses.replace(no_face, hidden_hand_parts=())).numpy())


def test_skin_reference_is_a_warm_median_of_enough_hand_gaussians():
    from reconstruct.appearance.hair import SKIN_MIN_COUNT, skin_reference
    n = SKIN_MIN_COUNT
    for tone in [(0.9, 0.7, 0.6), (0.45, 0.3, 0.22), (0.8, 0.55, 0.45)]:
        np.testing.assert_allclose(skin_reference(np.tile(tone, (n, 1))), tone)
    for glove in [(0.05, 0.05, 0.05), (0.5, 0.5, 0.5), (0.2, 0.6, 0.3), (0.2, 0.2, 0.6)]:
        assert skin_reference(np.tile(glove, (n, 1))) is None
    assert skin_reference(np.tile((0.9, 0.7, 0.6), (n - 1, 1))) is None
    # the median, not the mean: a few dark edge Gaussians do not move it
    cols = np.r_[np.tile((0.9, 0.7, 0.6), (n, 1)), np.zeros((n // 3, 3))]
    np.testing.assert_allclose(skin_reference(cols), (0.9, 0.7, 0.6))


def _tilted_arm(tilt_deg: float, radius=0.045, length=0.3, n_theta=48, n_along=60):
    """Points on a tube whose axis lies in the x-z plane, ``tilt_deg`` from upright (an arm in
    anny's rest pose: about 40-50 degrees); theta = 0 faces the front (-Y), theta = 90 degrees the
    side the axis is tilted towards (up, for an arm). Returns positions, theta."""
    th, s = np.meshgrid(np.linspace(-np.pi, np.pi, n_theta, endpoint=False), np.linspace(-length / 2, length / 2, n_along))
    th, s = th.ravel(), s.ravel()
    t = np.radians(tilt_deg)
    axis, across = np.array([np.sin(t), 0.0, np.cos(t)]), np.array([np.cos(t), 0.0, -np.sin(t)])
    pos = np.array([0.3, 0.0, 1.3]) + s[:, None] * axis + radius * (np.sin(th)[:, None] * across - np.cos(th)[:, None] * [0, 1, 0])
    return pos, th


def test_a_limb_seen_far_less_than_its_twin_takes_the_twins_colours():
    """The green-jacket photo's right upper arm kept 71 trusted texels (its sleeve was seen only at
    grazing angles), 70 of them the white sweater the fit laid it over, against the left's 395 of
    sleeve green. More than ``twin_below``, but under ``twin_share`` of its twin's: filled from the
    twin (mirrored in x), its back is green; filled from its own, white."""
    pos_l, th = _tilted_arm(45.0)
    pos_r = pos_l * [-1.0, 1.0, 1.0]
    pos = np.r_[pos_l, pos_r]
    parts = np.r_[np.full(len(th), PART_INDEX["upperarm.L"]), np.full(len(th), PART_INDEX["upperarm.R"])]
    seen_l = seen_front(th, 95)
    strip = seen_l & (np.degrees(th) < -60)  # the right arm: a strip of its underside
    col = np.tile(GREEN, (len(pos), 1))
    col[len(th):][strip] = WHITE
    seen = np.r_[seen_l, strip]
    cfg = WrapFillConfig(smooth_sweeps=0)
    assert cfg.twin_below <= strip.sum() < cfg.twin_share * seen_l.sum()  # the case the rule is for
    back_r = np.r_[np.zeros(len(th), bool), ~strip]
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    np.testing.assert_allclose(out[back_r], np.tile(GREEN, (back_r.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(out[len(th):][strip], np.tile(WHITE, (strip.sum(), 1)), atol=1e-6)  # its seen front stays
    old = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(smooth_sweeps=0, twin_share=0.0)).numpy()
    assert (np.abs(old[back_r] - WHITE).max(1) < 0.05).mean() > 0.9


def test_hair_falling_over_a_photos_shoulders_is_not_carried_round_the_back():
    """Long hair falls in front of both shoulders of a red dress seen from the front only. The
    torso's seen Gaussians in the hair's colours (the head's hair, lit and shadowed strands) are no
    source of its back, which takes the dress's red; the hair stays on the front. Without the rule
    the band at the shoulders' height is hair on both sides and the upper back turns brown (the
    red-dress photo)."""
    head, _, head_seen, head_truth = front_only_head()
    torso, th = cylinder(radius=0.15, height=0.5, n_theta=96, n_z=100, z0=1.0)
    deg = np.degrees(th)
    front = np.abs(deg) <= 85
    strands = (torso[:, 2] > 1.32) & (np.abs(deg) > 25)  # both sides of the upper front
    col_t = np.tile(RED, (len(torso), 1))
    lit = (np.arange(len(torso)) % 3) == 0
    col_t[strands] = np.where(lit[strands, None], HAIR + 0.08, HAIR)  # two shades of the hair
    pos = np.r_[head, torso]
    parts = np.r_[np.full(len(head), PART_INDEX["head"]), np.full(len(torso), PART_INDEX["torso"])]
    seen = np.r_[head_seen, front]
    col = np.r_[np.where(head_seen[:, None], head_truth, 0.5), np.where(front[:, None], col_t, 0.5)]
    back = np.r_[np.zeros(len(head), bool), ~front]
    out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    assert np.abs(out[back] - RED).max(1).max() < 0.05
    np.testing.assert_allclose(out[seen], col[seen].astype(np.float32), atol=1e-6)  # the front keeps its hair
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_over_parts=())).numpy()
    upper_back = back & (pos[:, 2] > 1.35)
    assert np.abs(off[upper_back] - HAIR).max(1).mean() < 0.1
    # a brown dress under brown hair, with a red hem: the hair's colours are the dress's own and stay
    # sources; the back is brown, not the red that is left without them
    dress = np.where((torso[:, 2] < 1.12)[:, None], RED, HAIR + 0.04)
    brown = np.where(front[:, None], np.where(strands[:, None], col_t, dress), 0.5)
    same = wrap_fill_colors(pos, parts, seen, np.r_[col[:len(head)], brown], None).numpy()
    mid_back = back & (pos[:, 2] > 1.2) & (pos[:, 2] < 1.3)
    assert np.abs(same[mid_back] - HAIR).max(1).max() < 0.1
    # a head the video saw behind its centre: no photo, the rule stands down (the fill as without it)
    head_deg = np.abs(np.degrees(np.arctan2(head[:, 0], -head[:, 1])))
    seen_round = np.r_[head_deg <= 110, front]  # 20 degrees past its sides: 11 % of its back
    col_round = np.r_[np.where(seen_round[:len(head), None], head_truth, 0.5), col[len(head):]]
    round_ = wrap_fill_colors(pos, parts, seen_round, col_round, None).numpy()
    off_round = wrap_fill_colors(pos, parts, seen_round, col_round, None, WrapFillConfig(hair_over_parts=())).numpy()
    np.testing.assert_allclose(round_[back], off_round[back], atol=1e-6)
    assert np.abs(round_[upper_back] - HAIR).max(1).mean() < 0.1


def test_the_back_behind_hair_over_a_photos_chest_is_not_mirrored_from_the_hairs_edge():
    """Strands over one side of a red dress's chest, seen from the front only, edged by cloth
    blended with them (a light red, like the satin's sheen down the sides). The strands are no
    source; the mirror of the back behind them found the blended edge beside them, whose colour the
    sheen let through the palette gate, and painted a light patch there (the red-dress photo
    trained again). Its image lies nearer the hair than any source: the back takes the band's red."""
    head, _, head_seen, head_truth = front_only_head()
    torso, th = cylinder(radius=0.15, height=0.5, n_theta=96, n_z=100, z0=1.0)
    deg = np.degrees(th)
    upper = torso[:, 2] > 1.32
    front = np.abs(deg) <= 85
    light = RED + np.array([0.05, 0.2, 0.2])
    col_t = np.tile(RED, (len(torso), 1))
    col_t[(np.abs(deg) > 75) & (np.arange(len(torso)) % 5 == 0)] = light  # sheen down both sides
    strands = upper & (deg > -50) & (deg < -35)
    edge = upper & (((deg >= -56) & (deg <= -50)) | ((deg >= -35) & (deg <= -29)))
    col_t[strands] = HAIR
    col_t[edge] = light
    pos = np.r_[head, torso]
    parts = np.r_[np.full(len(head), PART_INDEX["head"]), np.full(len(torso), PART_INDEX["torso"])]
    seen = np.r_[head_seen, front]
    col = np.r_[np.where(head_seen[:, None], head_truth, 0.5), np.where(front[:, None], col_t, 0.5)]
    # behind the strands' middle (its mirror image through the torso lies at -43 to -40 degrees)
    behind = np.r_[np.zeros(len(head), bool), ~front & upper & (deg < -133) & (deg > -143)]
    cfg = WrapFillConfig(front_only_median=0, smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    assert np.abs(out[behind] - RED).max() < 1e-6
    old = wrap_fill_colors(pos, parts, seen, col, None, dataclasses.replace(cfg, hair_over_mirror=False)).numpy()
    assert (np.abs(old[behind] - light).max(1) < 1e-6).mean() > 0.9  # the case is real


def test_the_hair_rule_on_a_part_with_no_seen_gaussians():
    """An upper arm no view saw, beside a front-only head and a torso with hair over it: the hair rule
    has no sources of the arm to read (it read a median of none, with numpy's warning, on the
    grey-skirt photo), and the arm takes the torso's colours as without the rule."""
    import warnings
    head, _, head_seen, head_truth = front_only_head()
    torso, th = cylinder(radius=0.15, height=0.5, n_theta=96, n_z=100, z0=1.0)
    front = np.abs(np.degrees(th)) <= 85
    arm, _ = _tilted_arm(45.0)
    pos = np.r_[head, torso, arm]
    parts = np.r_[np.full(len(head), PART_INDEX["head"]), np.full(len(torso), PART_INDEX["torso"]),
                  np.full(len(arm), PART_INDEX["upperarm.L"])]
    seen = np.r_[head_seen, front, np.zeros(len(arm), bool)]
    col = np.r_[np.where(head_seen[:, None], head_truth, 0.5), np.tile(RED, (len(torso), 1)), np.full((len(arm), 3), 0.5)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = wrap_fill_colors(pos, parts, seen, col, None).numpy()
    off = wrap_fill_colors(pos, parts, seen, col, None, WrapFillConfig(hair_over_parts=())).numpy()
    a = slice(len(head) + len(torso), None)
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out[a], off[a], atol=1e-6)


def test_a_photos_throat_takes_what_the_images_show_there():
    # a dress with an open collar, a photo with the head level: the chin hides the throat (the
    # torso's top rows in front, unseen). The neckline is left out of the band (the back is cloth
    # at its heights), and the throat took the band's red: a red bib under the chin once the walk
    # lifts the head. Within ``occluded_reach`` of the neck it takes what the image shows where it
    # lies (``occluded_colors``); farther down, and round the back, the fill stands
    shade = np.array([0.45, 0.3, 0.22])
    pos, parts, seen, n_tube = _torso_and_neck(70)
    deg = np.abs(np.degrees(np.arctan2(pos[:, 0], -pos[:, 1])))
    z = pos[:, 2]
    tube = np.arange(len(pos)) < n_tube
    col = np.tile(RED, (len(pos), 1))
    col[tube & (deg < 30) & (z > 1.36)] = SKIN
    d_neck = cKDTree(pos[parts == PART_INDEX["neck"]]).query(pos)[0]
    throat = (parts == PART_INDEX["torso"]) & (d_neck < 0.045) & (pos[:, 1] < -0.02)  # the top's front
    assert throat.sum() > 10
    chest = tube & (deg < 20) & (z > 1.2) & (z < 1.3)  # hidden lower down (folded arms)
    seen &= ~throat & ~chest
    occluded = np.full((len(pos), 3), np.nan)
    occluded[throat | chest] = shade
    back = tube & (pos[:, 1] > 0.05) & (z > 1.42)
    cfg = WrapFillConfig(front_only_median=200, smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg, occluded_colors=occluded).numpy()
    assert np.abs(out[throat] - shade).max() < 1e-6
    assert (np.abs(out[chest] - shade).max(1) > 0.1).all()
    assert np.abs(out[back] - RED).max() < 1e-6
    without = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    assert np.abs(without[throat] - RED).max(1).mean() < 0.05  # the case is real
    # a torso seen behind (a video) keeps its fill
    round_ = np.r_[np.ones(n_tube, bool), seen[n_tube:]] & ~throat
    kept = wrap_fill_colors(pos, parts, round_, col, None, cfg, occluded_colors=occluded).numpy()
    assert np.array_equal(kept, wrap_fill_colors(pos, parts, round_, col, None, cfg).numpy())


def test_a_neck_with_no_trusted_gaussians_takes_what_the_images_show_there():
    # a photo's neck hidden by the chin: no trusted Gaussian of its own, so it took the nearest
    # filled colour of any part (the collar's red). Given the colours the image shows where its
    # Gaussians facing the camera project (``occluded_colors``), its front takes them -- the rest
    # of its front the nearest of them -- and its back is left to the fallback
    shade = np.array([0.45, 0.3, 0.22])
    pos, parts, seen, n_tube = _torso_and_neck(70)
    col = np.tile(RED, (len(pos), 1))
    neck = parts == PART_INDEX["neck"]
    occluded = np.full((len(pos), 3), np.nan)
    read = neck & (pos[:, 1] < -0.025)  # facing the camera within 60 degrees
    occluded[read] = shade
    cfg = WrapFillConfig(front_only_median=0, smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg, occluded_colors=occluded).numpy()
    # the back's lower rows: the torso's filled back behind them is nearer than the front (with no
    # head above in this scene, its top rows take the front)
    front, back = neck & (pos[:, 1] < 0), neck & (pos[:, 1] > 0.04) & (pos[:, 2] < 1.54)
    assert (front & ~read).any() and back.any()
    assert np.abs(out[front] - shade).max() < 1e-6
    assert (np.abs(out[back] - shade).max(1) > 0.1).all()
    without = wrap_fill_colors(pos, parts, seen, col, None, cfg).numpy()
    assert (np.abs(without[front] - shade).max(1) > 0.1).all()  # the case is real
    off = wrap_fill_colors(pos, parts, seen, col, None, dataclasses.replace(cfg, occluded_parts=()),
                           occluded_colors=occluded).numpy()
    assert np.array_equal(off, without)
    with pytest.raises(ValueError, match=r"occluded_colors must have shape \("):
        wrap_fill_colors(pos, parts, seen, col, None, cfg, occluded_colors=occluded[:-1])


def _open_coat(arm_colour):
    """A photo of an open coat over a light dress: the torso (a tube) under the coat's layer below
    1.1 m (each Gaussian hidden by the nearest layer Gaussian), its chest seen above that only down
    the middle (the dress between the open fronts; the sides hidden by the arms and the hair), two
    upper arms seen in front in ``arm_colour``, the layer seen in front in the coat's brown."""
    brown, light = np.array([0.70, 0.50, 0.37]), np.array([0.90, 0.75, 0.65])
    tp, tth = cylinder(radius=0.15, height=0.5, n_theta=96, n_z=60, z0=1.0)
    lp, lth = cylinder(radius=0.17, height=0.3, n_theta=92, n_z=22, z0=0.8)
    arms, arm_th, arm_part = [], [], []
    for x, name in ((-0.22, "upperarm.R"), (0.22, "upperarm.L")):
        ap, ath = cylinder(radius=0.05, height=0.3, n_theta=24, n_z=20, z0=1.2)
        arms.append(ap + [x, 0.0, 0.0])
        arm_th.append(ath)
        arm_part.append(np.full(len(ap), PART_INDEX[name]))
    pos = np.concatenate([tp, lp, *arms])
    parts = np.concatenate([np.full(len(tp), PART_INDEX["torso"]), np.full(len(lp), GARMENT_PART), *arm_part])
    th = np.concatenate([tth, lth, *arm_th])
    deg = np.abs(np.degrees(th))
    torso, layer = parts == PART_INDEX["torso"], parts == GARMENT_PART
    arm = ~torso & ~layer
    col = np.tile(light, (len(pos), 1))
    col[layer] = brown
    col[arm] = arm_colour
    seen = (torso & (pos[:, 2] >= 1.1) & (deg <= 25)) | (layer & (deg <= 80)) | (arm & (deg <= 90))
    under = np.full(len(pos), -1)
    low = np.flatnonzero(torso & (pos[:, 2] < 1.1))
    under[low] = np.flatnonzero(layer)[cKDTree(pos[layer]).query(pos[low])[1]]
    back = torso & (pos[:, 1] > 0.05) & (pos[:, 2] > 1.15)
    return pos, parts, seen, col, under, back, brown, light


def test_an_open_coats_back_above_the_layer_takes_the_coats_colour():
    # the torso's band above the layer is the dress down the middle of the chest, and carried round
    # it drew a light upper back under a brown coat (the group photo's second woman). The sleeves
    # and the layer agree: the back takes their colour; bare arms (skin) leave the fill as it was,
    # and so does a torso seen behind its centre (a video)
    pos, parts, seen, col, under, back, brown, light = _open_coat(np.array([0.66, 0.46, 0.33]))
    cfg = WrapFillConfig(smooth_sweeps=0)
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg, under_layer=under).numpy()
    off = wrap_fill_colors(pos, parts, seen, col, None, dataclasses.replace(cfg, coat_back=False),
                           under_layer=under).numpy()
    assert np.abs(off[back] - light).max(1).mean() < 0.05  # the case is real
    coat = np.median(np.r_[col[seen & (parts != PART_INDEX["torso"])]], axis=0)
    assert np.abs(out[back] - coat).max() < 1e-6 and np.abs(coat - brown).max() < 0.05
    front = seen & (parts == PART_INDEX["torso"])
    assert np.abs(out[front] - col[front]).max() < 1e-6  # what the photo shows stays
    skin = np.array([0.85, 0.62, 0.50])
    pos, parts, seen, col, under, back, _, _ = _open_coat(skin)
    bare = wrap_fill_colors(pos, parts, seen, col, None, cfg, under_layer=under).numpy()
    assert np.array_equal(bare, wrap_fill_colors(pos, parts, seen, col, None, dataclasses.replace(cfg, coat_back=False),
                                                 under_layer=under).numpy())
    pos, parts, seen, col, under, back, _, _ = _open_coat(np.array([0.66, 0.46, 0.33]))
    round_ = seen | ((parts == PART_INDEX["torso"]) & (pos[:, 1] > 0.1) & (pos[:, 2] > 1.3))
    video = wrap_fill_colors(pos, parts, round_, col, None, cfg, under_layer=under).numpy()
    assert np.array_equal(video, wrap_fill_colors(pos, parts, round_, col, None, dataclasses.replace(cfg, coat_back=False),
                                                  under_layer=under).numpy())


def test_a_coat_whose_sleeves_are_lit_brighter_than_its_skirts_still_gives_its_back():
    """Most of each sleeve lit (0.25 brighter than the brown, the medians out of tolerance): with a
    share of the arms within the tolerance of the layer's median (``coat_arm_share``) the colour is
    the median of those and the layer's (a float64 reference), and the back takes it; under the
    share (sleeves with 6 % in the brown), with the share rule off, and for bare arms: none."""
    from reconstruct.appearance.wrap_fill import coat_colour

    brown = np.array([0.66, 0.46, 0.33])
    pos, parts, seen, col, under, back, _, light = _open_coat(brown)
    arm = np.isin(parts, [PART_INDEX["upperarm.L"], PART_INDEX["upperarm.R"]])
    lit = arm & (pos[:, 2] > 1.29)  # the upper 70 % of each sleeve
    col[lit] = brown + 0.25
    cfg = WrapFillConfig(smooth_sweeps=0)
    layer = (parts == GARMENT_PART) & seen
    assert (np.abs(np.median(col[arm & seen], 0) - np.median(col[layer], 0)) > cfg.palette_tolerance).any()
    near = arm & seen & (np.abs(col - np.median(col[layer], 0)) <= cfg.palette_tolerance).all(1)
    want = np.median(col[near | layer].astype(np.float64), 0)
    got = coat_colour(col, parts, seen, cfg)
    assert got is not None and np.abs(got - want).max() < 1e-12
    out = wrap_fill_colors(pos, parts, seen, col, None, cfg, under_layer=under).numpy()
    assert np.abs(out[back] - want).max() < 1e-6
    assert coat_colour(col, parts, seen, dataclasses.replace(cfg, coat_arm_share=0.0)) is None
    mostly = col.copy()
    mostly[arm & ~lit & (np.arange(len(pos)) % 5 != 0)] = brown + 0.25  # 6 % of each sleeve in the brown
    assert 0 < (arm & seen & (np.abs(mostly - brown) <= 0.12).all(1)).sum() < 0.2 * (arm & seen).sum()
    assert coat_colour(mostly, parts, seen, cfg) is None
    bare = col.copy()
    bare[arm] = np.array([0.85, 0.62, 0.50])
    assert coat_colour(bare, parts, seen, cfg) is None


def _photo_of(pos, colours, front, strands_to=None, scale=100.0, size=(110, 70), top=1.80):
    """A frontal orthographic picture (``scale`` px per metre, row 0 at z = ``top``, the middle column
    at x = 0) of the ``front`` Gaussians in ``colours``, their pixels grown by one to close the gaps,
    and the view of all ``pos``. ``strands_to``: hair drawn down both sides of the neck, over the
    torso, to that height."""
    from scipy import ndimage

    from reconstruct.appearance.cut_fill import FrameView

    h, w = size
    uv = np.c_[w / 2 + scale * pos[:, 0], scale * (top - pos[:, 2])]
    image = np.zeros((h, w, 3))
    mask = np.zeros((h, w), bool)
    order = np.argsort(-pos[:, 1])  # far ones first, the nearest drawn last
    for i in order[front[order]]:
        x, y = int(uv[i, 0]), int(uv[i, 1])
        image[y, x], mask[y, x] = colours[i], True
    grown = ndimage.binary_dilation(mask, iterations=1) & ~mask
    idx = ndimage.distance_transform_edt(~mask, return_distances=False, return_indices=True)
    image[grown] = image[idx[0][grown], idx[1][grown]]
    mask |= grown
    if strands_to is not None:
        xs = np.arange(w)[None, :]
        ys = np.arange(h)[:, None]
        side = (np.abs(np.abs(xs - w / 2) - 0.10 * scale) <= 2.5) & (ys >= scale * (top - 1.72)) & (ys < scale * (top - strands_to))
        image[side] = HAIR
        mask |= side
    return FrameView(uv, np.ones(len(pos), bool), image, mask.astype(np.float32))


def _head_neck_torso():
    """A head (hair round a face, a nose), a neck and a torso in a blue shirt, built as cylinders:
    positions, parts, true colours, and the seen flags of a photo from the front."""
    head, th = cylinder(radius=0.09, height=0.22, n_theta=72, n_z=44, z0=1.55)
    deg = np.abs(np.degrees(th)) - 1e-9
    head_col = np.where(((head[:, 2] < 1.70) & (deg < 50))[:, None], SKIN, HAIR)
    nose = np.array([[0.0, -0.11, 1.63]])
    neck, _ = cylinder(radius=0.05, height=0.10, n_theta=40, n_z=20, z0=1.45)
    torso, th_t = cylinder(radius=0.15, height=0.44, n_theta=96, n_z=88, z0=1.0)
    pos = np.r_[head, nose, neck, torso]
    parts = np.r_[np.full(len(head) + 1, PART_INDEX["head"]), np.full(len(neck), PART_INDEX["neck"]),
                  np.full(len(torso), PART_INDEX["torso"])]
    truth = np.r_[head_col, [SKIN], np.tile(SKIN, (len(neck), 1)), np.tile(BLUE, (len(torso), 1))]
    front = pos[:, 1] < np.array([pos[parts == p, 1].mean() for p in parts]) + 1e-9
    seen = np.r_[deg <= 80, True, front[len(head) + 1:]]
    return pos, parts, truth, seen


def test_long_hair_in_a_photo_covers_the_back_of_the_neck_and_shoulders():
    """A head seen from the front only, a neck and a torso in a blue shirt; the photo shows hair
    falling either side of the neck onto the shoulders, to 1.35 m. From behind, the hair covers the
    back of the neck and the upper back between its strands, to about that height, in its colour
    (``hair_back_parts``, ``long_hair.py``); hair cut at the jaw leaves them the shirt's and the
    neck's, as does a fill without the images."""
    pos, parts, truth, seen = _head_neck_torso()
    col = np.where(seen[:, None], truth, 0.5)
    long_hair = _photo_of(pos, truth, seen, strands_to=1.35)
    hair = long_hair_colors(pos, parts, seen, col, [long_hair]).numpy()
    assert np.isnan(hair[seen]).all()
    out = wrap_fill_colors(pos, parts, seen, col, None, hair_colors=hair).numpy()
    torso_back = (parts == PART_INDEX["torso"]) & ~seen
    under = torso_back & (pos[:, 2] > 1.38) & (np.abs(pos[:, 0]) < 0.09)
    assert under.sum() > 50
    assert np.abs(out[under] - HAIR).max(1).mean() < 0.05
    neck_back = (parts == PART_INDEX["neck"]) & ~seen
    assert np.abs(out[neck_back] - HAIR).max(1).mean() < 0.05
    low = torso_back & (pos[:, 2] < 1.28)
    assert np.abs(out[low] - BLUE).max(1).max() < 0.05
    # the head's seen Gaussians keep their colours; a head that shows no hair reads none
    np.testing.assert_allclose(out[seen], col[seen].astype(np.float32), atol=1e-6)
    bald = np.where(seen[:, None] & (parts == PART_INDEX["head"])[:, None], SKIN, col)
    assert np.isnan(long_hair_colors(pos, parts, seen, bald, [long_hair]).numpy()).all()
    with pytest.raises(ValueError, match="hair_colors must have shape"):
        wrap_fill_colors(pos, parts, seen, col, None, hair_colors=hair[:-1])
    # without the images, and with hair cut at the jaw, the upper back is the shirt's
    for hair in (None, long_hair_colors(pos, parts, seen, col, [_photo_of(pos, truth, seen)])):
        plain = wrap_fill_colors(pos, parts, seen, col, None, hair_colors=hair).numpy()
        assert np.abs(plain[under] - BLUE).max(1).mean() < 0.05
        assert np.abs(plain[neck_back] - HAIR).max(1).mean() > 0.2


def test_long_hair_over_a_garment_layer_covers_the_layers_back():
    """The same photo with a coat's layer (``GARMENT_PART``, 2 cm off the torso) over the back from
    1.20 m up to 1.42 m, hiding the torso under it: the hair covers the layer's back, not the hidden
    torso; the layer's back below the hair keeps the coat's colour."""
    pos, parts, truth, seen = _head_neck_torso()
    th, z = np.meshgrid(np.linspace(-np.pi, np.pi, 96, endpoint=False), np.linspace(1.20, 1.42, 44))
    layer = np.c_[0.17 * np.sin(th.ravel()), -0.17 * np.cos(th.ravel()), z.ravel()]
    torso = parts == PART_INDEX["torso"]
    hidden = torso & (pos[:, 2] >= 1.20) & (pos[:, 2] <= 1.42)
    under = np.full(len(pos) + len(layer), -1)
    under[np.flatnonzero(hidden)] = len(pos) + cKDTree(layer).query(pos[hidden])[1]
    pos = np.r_[pos, layer]
    parts = np.r_[parts, np.full(len(layer), GARMENT_PART)]
    truth = np.r_[truth, np.tile(GREEN, (len(layer), 1))]
    seen = np.r_[seen & ~hidden, layer[:, 1] < 0]
    hidden = np.r_[hidden, np.zeros(len(layer), bool)]
    col = np.where(seen[:, None], truth, 0.5)
    photo = _photo_of(pos, truth, seen, strands_to=1.30)
    hair = long_hair_colors(pos, parts, seen, col, [photo], under_layer=under).numpy()
    out = wrap_fill_colors(pos, parts, seen, col, None, under_layer=under, hair_colors=hair).numpy()
    layer_back = (parts == GARMENT_PART) & ~seen
    covered = layer_back & (pos[:, 2] > 1.33) & (np.abs(pos[:, 0]) < 0.08)
    assert covered.sum() > 30
    assert np.abs(out[covered] - HAIR).max(1).mean() < 0.05
    assert np.isnan(hair[hidden]).all()  # the torso under the cloth is no candidate
    assert np.abs(out[layer_back & (pos[:, 2] < 1.26)] - GREEN).max(1).max() < 0.05
    # without the layer among the parts the hair covers, its back is the coat's
    cfg = WrapFillConfig(hair_back_parts=("head", "neck", "torso"))
    bare = long_hair_colors(pos, parts, seen, col, [photo], config=cfg, under_layer=under).numpy()
    assert np.isnan(bare[covered]).all()
