"""The coverage metrics of evaluation: hole fraction (rendered alpha < 0.9 at least 2 px inside the
mask) and alpha IoU, on hand-made alpha maps and on renders with known gaps."""

import numpy as np
import pytest
import torch

from reconstruct.avatar.model import PosedGaussians
from reconstruct.camera import Camera
from reconstruct.train.evaluate import alpha_iou, hole_fraction, inner_mask, upsample
from reconstruct.train.render import render_avatar


def test_inner_mask_is_two_pixels_inside():
    mask = torch.zeros(20, 20, dtype=torch.bool)
    mask[5:15, 4:16] = True  # 10 x 12
    inner = inner_mask(mask)
    assert inner.sum() == 6 * 8
    assert inner[7:13, 6:14].all()
    # the image border is not background: a full mask keeps every pixel
    assert inner_mask(torch.ones(6, 6, dtype=torch.bool)).all()


def test_hole_fraction_of_a_known_hole():
    mask = torch.zeros(40, 40, dtype=torch.bool)
    mask[5:35, 5:35] = True  # inner region 26 x 26 = 676 pixels
    alpha = torch.ones(40, 40)
    assert hole_fraction(alpha, mask) == 0.0
    alpha[10:14, 20:25] = 0.5  # a 4 x 5 hole well inside
    alpha[5:7, 5:35] = 0.0  # missing alpha on the mask's rim: not counted (within 2 px of the edge)
    assert hole_fraction(alpha, mask) == pytest.approx(20 / 676)
    alpha[10, 10] = 0.899  # just below the threshold counts, at it does not
    alpha[11, 11] = 0.9
    assert hole_fraction(alpha, mask) == pytest.approx(21 / 676)
    assert hole_fraction(alpha, torch.zeros(40, 40, dtype=torch.bool)) is None


def test_alpha_iou():
    mask = torch.zeros(10, 10, dtype=torch.bool)
    mask[:, :5] = True
    alpha = torch.zeros(10, 10)
    alpha[:, 2:7] = 0.8  # 30 of 50 overlap; union 70
    assert alpha_iou(alpha, mask) == pytest.approx(30 / 70)
    assert alpha_iou(torch.zeros(4, 4), torch.zeros(4, 4, dtype=torch.bool)) is None


def test_upsample_keeps_constant_images_and_mask_threshold():
    img = np.full((8, 8, 3), 0.25, np.float32)
    up = upsample(img, 2, "cpu")
    assert up.shape == (16, 16, 3) and torch.allclose(up, torch.full_like(up, 0.25))
    m = np.zeros((8, 8), np.float32)
    m[2:6, 2:6] = 1
    assert int((upsample(m, 2, "cpu") > 0.5).sum()) == 64  # the 4 x 4 square becomes 8 x 8


def _grid_splats(spacing: float, std: float, n: int = 9) -> PosedGaussians:
    """An n x n grid of isotropic Gaussians in the plane z = 2 facing a camera at the origin."""
    xs = (torch.arange(n, dtype=torch.float32) - (n - 1) / 2) * spacing
    yy, xx = torch.meshgrid(xs, xs, indexing="ij")
    means = torch.stack([xx.flatten(), yy.flatten(), torch.full((n * n,), 2.0)], 1)
    N = n * n
    quats = torch.zeros(N, 4)
    quats[:, 0] = 1
    return PosedGaussians(means, torch.tensor([[0.0, 0.0, -1.0]]).expand(N, 3).contiguous(), torch.full((N, 3), 0.7),
                          torch.full((N, 3), std), quats, torch.ones(N))


def _camera(size: int = 64) -> Camera:
    K = np.array([[60.0, 0, size / 2], [0, 60.0, size / 2], [0, 0, 1]])
    return Camera(K, np.eye(3), np.zeros(3), size, size, 0.1, 10.0, "test")


@pytest.mark.parametrize("std, holes", [(0.02, True), (0.06, False)])
def test_render_with_gaps_between_gaussians_has_holes(std, holes):
    """Gaussians 0.1 apart: std 0.02 leaves the background between them (alpha ~0 at the cell
    centres); std 0.06 covers the square."""
    cam = _camera()
    g = _grid_splats(0.1, std)
    bg = torch.zeros(3)
    alpha = render_avatar(g, cam, bg, normals=False).alpha
    # the mask: the square the grid spans (centres +- half a spacing), in pixels
    half = 0.45 * 60 / 2  # 4.5 spacings of 0.1 m at depth 2, focal 60
    mask = torch.zeros(64, 64, dtype=torch.bool)
    lo, hi = int(np.ceil(32 - half)), int(np.floor(32 + half))
    mask[lo:hi, lo:hi] = True
    frac = hole_fraction(alpha, mask)
    assert (frac > 0.3) if holes else (frac == 0.0)
