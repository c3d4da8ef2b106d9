"""benchmarks/error_split.py: the regions partition the image as morphology with a square window
does (scipy as the reference), and the split error adds up to the image's mean squared error; the
wavelength split puts cosines of known wavelength and amplitude in their own band with their
energy (a^2/2), the height split follows the mask, not the image."""

import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from benchmarks.error_split import _cuts, error_split, height_split, regions, wavelength_split


def _mask(h=40, w=36, seed=0):
    rng = np.random.default_rng(seed)
    m = np.zeros((h, w), bool)
    m[8:30, 6:22] = True
    m[0:5, 25:36] = True  # touches the image's top and right borders
    m[rng.integers(0, h, 12), rng.integers(0, w, 12)] = True  # specks
    return m


@pytest.mark.parametrize("band", [1, 2, 3])
def test_regions_match_binary_morphology(band):
    m = _mask()
    window = np.ones((2 * band + 1, 2 * band + 1), bool)
    # the image's border counts as foreground for the interior (eval's hole rule), as background for the edge
    ref_inner = ndimage.binary_erosion(m, window, border_value=1)
    ref_grown = ndimage.binary_dilation(m, window, border_value=0)
    interior, edge, outside = (r.numpy() for r in regions(torch.from_numpy(m), band))
    np.testing.assert_array_equal(interior, ref_inner)
    np.testing.assert_array_equal(edge, ref_grown & ~ref_inner)
    np.testing.assert_array_equal(outside, ~ref_grown)
    assert (interior.astype(int) + edge + outside == 1).all()


def test_the_split_adds_up_to_the_mean_squared_error():
    rng = np.random.default_rng(1)
    m = _mask()
    gt = rng.uniform(0, 1, m.shape + (3,))
    pred = np.clip(gt + rng.normal(0, 0.1, gt.shape), 0, 1)
    s = error_split(torch.from_numpy(pred).float(), torch.from_numpy(gt).float(), torch.from_numpy(m), band=2)
    se = ((pred.astype(np.float32).astype(np.float64) - gt.astype(np.float32)) ** 2).mean(-1)
    inner = ndimage.binary_erosion(m, np.ones((5, 5), bool), border_value=1)
    assert s["mse"] == pytest.approx(se.mean(), rel=1e-9)
    assert s["interior"] + s["edge"] + s["outside"] == pytest.approx(s["mse"], rel=1e-9)
    assert s["interior"] == pytest.approx(se[inner].sum() / se.size, rel=1e-9)
    assert s["interior_psnr"] == pytest.approx(-10 * math.log10(se[inner].mean()), rel=1e-9)
    assert s["foreground"] == pytest.approx(m.mean())


def test_an_error_inside_the_mask_is_read_as_interior_only():
    m = np.zeros((30, 30), bool)
    m[5:25, 5:25] = True
    gt = np.full((30, 30, 3), 0.5, np.float32)
    pred = gt.copy()
    pred[12:18, 12:18] += 0.2  # well inside: 7 px from the boundary
    s = error_split(torch.from_numpy(pred), torch.from_numpy(gt), torch.from_numpy(m), band=2)
    assert s["interior"] == pytest.approx(36 * 0.04 / 900, rel=1e-5)
    assert s["edge"] == 0 and s["outside"] == 0
    pred = gt.copy()
    pred[:, 0] = 0.9  # the image's left column: background, far from the mask
    s = error_split(torch.from_numpy(pred), torch.from_numpy(gt), torch.from_numpy(m), band=2)
    assert s["outside"] > 0 and s["interior"] == 0 and s["edge"] == 0
    assert s["interior_psnr"] == math.inf


def test_a_band_under_one_pixel_is_refused():
    with pytest.raises(ValueError, match="band must be at least 1 pixel, found 0"):
        regions(torch.ones(4, 4, dtype=torch.bool), 0)


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a))


def test_wavelength_split_puts_each_cosine_in_its_band_with_its_energy():
    H, W = 64, 96
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    gt = np.full((H, W, 3), 0.5)
    err = (0.05 * np.cos(2 * np.pi * x / 4)[..., None]          # 4 px: fine
           + 0.08 * np.cos(2 * np.pi * (x / 24 + y / 32))[..., None]  # 1/sqrt(1/24^2+1/32^2) = 19.2 px: pattern
           + 0.03 * np.cos(2 * np.pi * y / 64)[..., None]          # 64 px: coarse
           + np.array([0.02, -0.01, 0.04]))                         # the mean: coarse
    s = wavelength_split(_t(gt + err), _t(gt), (8, 48))
    assert s["fine"] == pytest.approx(0.05 ** 2 / 2, rel=1e-9)
    assert s["pattern"] == pytest.approx(0.08 ** 2 / 2, rel=1e-9)
    assert s["coarse"] == pytest.approx(0.03 ** 2 / 2 + np.mean(np.array([0.02, -0.01, 0.04]) ** 2), rel=1e-9)
    assert sum(s.values()) == pytest.approx((err ** 2).mean(), rel=1e-9)


def test_wavelength_split_adds_up_to_the_mean_squared_error_of_any_error():
    rng = np.random.default_rng(3)
    gt, pred = rng.uniform(0, 1, (2, 37, 29, 3))
    s = wavelength_split(_t(pred), _t(gt), (3, 11))
    assert min(s.values()) > 0
    assert sum(s.values()) == pytest.approx(((pred - gt) ** 2).mean(), rel=1e-9)
    with pytest.raises(ValueError, match="0 < A < B"):
        wavelength_split(_t(pred), _t(gt), (11, 3))


def test_height_split_follows_the_mask_not_the_image():
    H, W = 80, 40
    gt = np.full((H, W, 3), 0.5)

    def bands(top):  # a person 40 rows tall from row ``top``, an error over their lowest 10 rows and above them
        m = np.zeros((H, W), bool)
        m[top:top + 40, 10:30] = True
        pred = gt.copy()
        pred[top + 30:top + 40, 10:30] += 0.1
        pred[max(top - 5, 0):top, 0:5] += 0.2  # above the mask: the first band
        return height_split(_t(pred), _t(gt), _t(m), 4), pred

    for top in (5, 30):
        b, pred = bands(top)
        assert sum(b) == pytest.approx(((pred - gt) ** 2).mean(), rel=1e-9)
        assert b[3] == pytest.approx(10 * 20 * 0.01 / (H * W), rel=1e-9)
        assert b[1] == 0 and b[2] == 0
        assert b[0] == pytest.approx(5 * 5 * 0.04 / (H * W), rel=1e-9)
    with pytest.raises(ValueError, match="at least 1"):
        height_split(_t(gt), _t(gt), _t(np.ones((H, W), bool)), 0)


def test_wavelength_argument_is_checked():
    assert _cuts("8,64") == (8.0, 64.0)
    with pytest.raises(Exception, match="A,B"):
        _cuts("8")
    with pytest.raises(Exception, match="0 < A < B"):
        _cuts("64,8")
