"""benchmarks/error_split.py: the regions partition the image as morphology with a square window
does (scipy as the reference), and the split error adds up to the image's mean squared error."""

import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from benchmarks.error_split import error_split, regions


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
