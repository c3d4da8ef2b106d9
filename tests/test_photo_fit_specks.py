"""The photo benchmark's speck measure (benchmarks/photo_fit.py, ``speck_share``): light dots on a
surface count (dark ones too when asked), a smooth surface, a shading ramp and the edge between two
flat regions do not, and nothing outside the inside of the render does."""

import numpy as np

from benchmarks.photo_fit import SPECK_STEP, SPECK_WINDOW, speck_share


def _plate(h=80, w=120, value=0.3):
    rgb = np.full((h, w, 3), value)
    alpha = np.zeros((h, w))
    alpha[10:70, 10:110] = 1.0
    return rgb, alpha


def test_a_smooth_surface_a_ramp_and_an_edge_have_no_specks():
    rgb, alpha = _plate()
    assert speck_share(rgb, alpha) == 0.0
    ramp = rgb.copy()
    ramp[...] = np.linspace(0.1, 0.9, rgb.shape[1])[None, :, None]  # 0.007 per px: shading
    assert speck_share(ramp, alpha) == 0.0
    edge = rgb.copy()
    edge[:, 60:] = 0.9  # a dark half and a light half: the median follows each pixel's side
    assert speck_share(edge, alpha) == 0.0


def test_light_dots_count_by_their_pixels_inside_only():
    rgb, alpha = _plate()
    inside = np.zeros(alpha.shape, bool)
    r = SPECK_WINDOW // 2
    inside[10 + r:70 - r, 10 + r:110 - r] = True  # the window lies on alpha 1 only here
    for y, x in [(30, 30), (30, 60), (50, 90)]:  # 2 x 2 dots, SPECK_STEP + 0.1 brighter
        rgb[y:y + 2, x:x + 2] += SPECK_STEP + 0.1
    rgb[12, 12] += 0.6  # near the silhouette: outside the measured inside
    assert speck_share(rgb, alpha) == 12 / inside.sum()
    faint = _plate()[0]
    faint[30:32, 30:32] += SPECK_STEP - 0.05  # not bright enough
    assert speck_share(faint, alpha) == 0.0


def test_no_inside_gives_nan():
    rgb, alpha = _plate()
    assert np.isnan(speck_share(rgb, np.zeros_like(alpha)))


def test_dark_dots_count_only_when_asked():
    rgb, alpha = _plate(value=0.6)
    rgb[30:32, 30:32] -= SPECK_STEP + 0.1  # a 2 x 2 dark dash
    assert speck_share(rgb, alpha) == 0.0
    r = SPECK_WINDOW // 2
    inside = (70 - r - (10 + r)) * (110 - r - (10 + r))
    assert speck_share(rgb, alpha, dark=True) == 4 / inside
    rgb[50:52, 90:92] += SPECK_STEP + 0.1  # and a light one: both count
    assert speck_share(rgb, alpha, dark=True) == 8 / inside
