"""The mask's soft band coloured from inside (reconstruct.data.prepare.matting): on a person of known
colour composited over a white wall with a soft edge, the stored colour x mask is the person's
alone; nearest-inside semantics against a brute-force search; full pixels untouched without the
ring; with it, a mask wider than the person loses the wall in its first full pixels, the ring and
the band take the core's colour (against a brute-force search), a strap narrower than two rings
keeps its own; bad input."""

import numpy as np
import pytest

from reconstruct.data.prepare.matting import FULL, RING, decontaminate


def _composite(fg, bg=(1.0, 1.0, 1.0), size=48, radius=14.0, ramp=4.0):
    """A disc of colour ``fg`` over ``bg`` whose alpha falls linearly over ``ramp`` px at its edge."""
    yy, xx = np.mgrid[:size, :size].astype(float)
    r = np.hypot(yy - size / 2, xx - size / 2)
    alpha = np.clip((radius - r) / ramp + 1.0, 0.0, 1.0)
    fg = np.broadcast_to(np.asarray(fg, float), (size, size, 3))
    image = alpha[..., None] * fg + (1 - alpha[..., None]) * np.asarray(bg, float)
    return image, alpha, fg


def test_band_colour_is_the_persons_not_the_walls():
    image, alpha, fg = _composite((0.3, 0.4, 0.2))
    band = (alpha > 0) & (alpha < FULL)
    assert band.sum() > 100
    before = image * alpha[..., None]
    after = decontaminate(image, alpha, ring=0) * alpha[..., None]
    truth = fg * alpha[..., None]
    # the white wall's share made the stored band up to a quarter lighter; now it is the person's colour
    assert np.abs(before - truth)[band].max() > 0.15
    # (the nearest full pixel may itself hold up to 2 % of the wall: mask >= FULL)
    assert np.abs(after - truth)[band].max() <= (1 - FULL) * 0.8 + 1e-12
    # pixels the mask calls full keep their colour (a blend of at most 2 % wall)
    np.testing.assert_array_equal(after[~band], before[~band])


def test_nearest_inside_colour_against_brute_force():
    rng = np.random.default_rng(0)
    image = rng.random((20, 24, 3))
    mask = np.zeros((20, 24))
    mask[5:14, 6:17] = 1.0
    mask[3:5, 8:12] = 0.5
    mask[14:16, 10:20] = rng.uniform(0.1, 0.9, (2, 10))
    out = decontaminate(image, mask, ring=0)
    inside = np.argwhere(mask >= FULL)
    for y, x in np.argwhere(mask < FULL):
        d = np.hypot(*(inside - (y, x)).T)
        nearest = inside[d <= d.min() + 1e-9]
        assert any(np.array_equal(out[y, x], image[a, b]) for a, b in nearest), (y, x)
    np.testing.assert_array_equal(out[mask >= FULL], image[mask >= FULL])


def test_no_full_pixel_or_all_full_leaves_the_image_and_bad_sizes_are_named():
    image = np.random.default_rng(1).random((8, 8, 3))
    for mask in (np.full((8, 8), 0.5), np.ones((8, 8))):
        out = decontaminate(image, mask, ring=2)
        np.testing.assert_array_equal(out, image)
        assert out is not image
    with pytest.raises(ValueError, match=r"image \(8, 8\) and mask \(8, 9\) differ"):
        decontaminate(image, np.ones((8, 9)))
    with pytest.raises(ValueError, match=r"ring must be a whole number of pixels >= 0, found -1"):
        decontaminate(image, np.ones((8, 8)), ring=-1)


def test_a_mask_wider_than_the_person_loses_the_wall_in_its_first_full_pixels():
    # the person's disc ends 2 px inside where the mask calls it full: those pixels are the wall
    fg, wall = np.array([0.8, 0.6, 0.5]), np.array([0.1, 0.1, 0.1])
    image, alpha, _ = _composite(fg, bg=wall, radius=12.0, ramp=3.0)
    yy, xx = np.mgrid[:48, :48].astype(float)
    mask = np.clip((14.0 - np.hypot(yy - 24, xx - 24)) / 3.0 + 1.0, 0.0, 1.0)  # 2 px wider
    on = mask > 0
    dark_before = np.abs(decontaminate(image, mask, ring=0) - fg).max(-1)[on]
    assert dark_before.max() > 0.3  # the wall in the full pixels, carried out over the band
    after = decontaminate(image, mask, ring=RING)
    assert RING == 2
    # (the core's outermost pixels, 2 px in on the pixel grid, may hold a few per cent of wall)
    assert np.abs(after - fg).max(-1)[on].max() < 0.05


def _brute_ring(image, mask, ring, full=FULL):
    """decontaminate's ring rule by exhaustive search (no distance transforms): yields each pixel
    that takes another's colour with the pixels whose colour it may take (ties)."""
    h, w = mask.shape
    inside = mask >= full
    not_full = np.argwhere(~inside)
    grid = np.argwhere(np.ones((h, w), bool))
    depth = np.array([np.hypot(*(not_full - p).T).min() for p in grid]).reshape(h, w)
    core = inside & (depth > ring)
    cores, fulls = np.argwhere(core), np.argwhere(inside)
    for y, x in grid:
        if core[y, x]:
            continue
        d_in = 0.0 if inside[y, x] else np.hypot(*(fulls - (y, x)).T).min()
        dc = np.hypot(*(cores - (y, x)).T)
        if dc.min() <= d_in + ring + 1.5:
            choices = cores[dc <= dc.min() + 1e-9]
        elif inside[y, x]:
            continue
        else:
            df = np.hypot(*(fulls - (y, x)).T)
            choices = fulls[df <= df.min() + 1e-9]
        yield (y, x), [tuple(c) for c in choices]


def test_ring_semantics_against_brute_force():
    rng = np.random.default_rng(3)
    image = rng.random((22, 26, 3))
    mask = np.zeros((22, 26))
    mask[4:18, 5:20] = 1.0
    mask[2:4, 8:13] = rng.uniform(0.2, 0.9, (2, 5))
    mask[18:20, 6:16] = 0.5
    mask[8:11, 20:25] = 1.0  # a strap 3 px wide off the right side
    out = decontaminate(image, mask, ring=2)
    touched = set()
    for (y, x), choices in _brute_ring(image, mask, 2):
        touched.add((y, x))
        assert any(np.array_equal(out[y, x], image[a, b]) for a, b in choices), (y, x)
    untouched = [tuple(p) for p in np.argwhere(np.ones(mask.shape, bool)) if tuple(p) not in touched]
    for y, x in untouched:
        np.testing.assert_array_equal(out[y, x], image[y, x])


def test_a_strap_narrower_than_two_rings_keeps_its_own_colour():
    image = np.zeros((30, 40, 3))
    image[...] = (0.2, 0.3, 0.9)  # the body: blue
    mask = np.zeros((30, 40))
    mask[5:25, 5:22] = 1.0
    mask[12:15, 22:38] = 1.0  # a red strap 3 px wide, 16 px long
    image[12:15, 22:38] = (0.9, 0.1, 0.1)
    out = decontaminate(image, mask, ring=2)
    # past the ring's reach from the body the strap is red, not the body's blue
    np.testing.assert_array_equal(out[12:15, 27:38], image[12:15, 27:38])
