"""The mask's soft band coloured from inside (reconstruct.data.prepare.matting): on a person of known
colour composited over a white wall with a soft edge, the stored colour x mask is the person's
alone; nearest-inside semantics against a brute-force search; full pixels untouched; bad input."""

import numpy as np
import pytest

from reconstruct.data.prepare.matting import FULL, decontaminate


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
    after = decontaminate(image, alpha) * alpha[..., None]
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
    out = decontaminate(image, mask)
    inside = np.argwhere(mask >= FULL)
    for y, x in np.argwhere(mask < FULL):
        d = np.hypot(*(inside - (y, x)).T)
        nearest = inside[d <= d.min() + 1e-9]
        assert any(np.array_equal(out[y, x], image[a, b]) for a, b in nearest), (y, x)
    np.testing.assert_array_equal(out[mask >= FULL], image[mask >= FULL])


def test_no_full_pixel_or_all_full_leaves_the_image_and_bad_sizes_are_named():
    image = np.random.default_rng(1).random((8, 8, 3))
    for mask in (np.full((8, 8), 0.5), np.ones((8, 8))):
        out = decontaminate(image, mask)
        np.testing.assert_array_equal(out, image)
        assert out is not image
    with pytest.raises(ValueError, match=r"image \(8, 8\) and mask \(8, 9\) differ"):
        decontaminate(image, np.ones((8, 9)))
