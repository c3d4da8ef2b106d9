"""PSNR: known values, scikit-image agreement, masks, batching and input checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.metrics import peak_signal_noise_ratio

from reconstruct.metrics import psnr


def _pair(shape=(2, 24, 32, 3), seed=0):
    gen = torch.Generator().manual_seed(seed)
    target = torch.rand(shape, generator=gen, dtype=torch.float64)
    pred = (target + 0.1 * torch.randn(shape, generator=gen, dtype=torch.float64)).clamp(0, 1)
    return pred, target


def test_constant_error_gives_known_value():
    target = torch.full((8, 8, 3), 0.5)
    assert psnr(target + 0.1, target).item() == pytest.approx(20.0, abs=1e-4)
    assert psnr(target * 255 + 25.5, target * 255, data_range=255.0).item() == pytest.approx(20.0, abs=1e-4)


def test_matches_skimage_per_image():
    pred, target = _pair()
    ours = psnr(pred, target, reduction="none")
    assert ours.shape == (2,)
    for i in range(2):
        ref = peak_signal_noise_ratio(target[i].numpy(), pred[i].numpy(), data_range=1.0)
        assert ours[i].item() == pytest.approx(ref, abs=1e-10)
    assert psnr(pred, target).item() == pytest.approx(ours.mean().item())
    assert psnr(pred[0], target[0]).item() == pytest.approx(ours[0].item())


def test_mask_restricts_mse_to_masked_pixels():
    target = torch.rand(16, 16, 3, dtype=torch.float64)
    mask = torch.zeros(16, 16, dtype=torch.bool)
    mask[4:12, 2:9] = True
    error = torch.full_like(target, 0.5)
    error[mask] = 0.1  # error 0.1 inside the mask, 0.5 outside
    pred = target + error
    assert psnr(pred, target, mask).item() == pytest.approx(20.0, abs=1e-9)
    assert psnr(pred, target, mask[..., None].double()).item() == pytest.approx(20.0, abs=1e-9)
    expected_unmasked = -10 * math.log10(float(((pred - target) ** 2).mean()))
    assert psnr(pred, target).item() == pytest.approx(expected_unmasked, abs=1e-9)


def test_batched_mask_per_image():
    pred, target = _pair()
    mask = torch.rand(2, 24, 32) > 0.5
    values = psnr(pred, target, mask, reduction="none")
    for i in range(2):
        sel = mask[i].numpy()
        mse = float(((pred[i].numpy() - target[i].numpy()) ** 2)[sel].mean())
        assert values[i].item() == pytest.approx(-10 * np.log10(mse), abs=1e-9)


def test_identical_images_give_inf():
    x = torch.rand(8, 8, 3)
    assert math.isinf(psnr(x, x).item())


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"mask": torch.zeros(24, 32, dtype=torch.bool)}, "mask is empty for image"),
        ({"mask": torch.ones(24, 31, dtype=torch.bool)}, "mask shape (24, 31) does not match"),
        ({"data_range": 0.0}, "data_range must be positive"),
        ({"reduction": "sum"}, "reduction must be one of"),
    ],
)
def test_errors(kwargs, message):
    pred, target = _pair(shape=(24, 32, 3))
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        psnr(pred, target, **kwargs)


def test_shape_and_type_errors():
    with pytest.raises(ValueError, match="shapes differ"):
        psnr(torch.rand(8, 8, 3), torch.rand(8, 9, 3))
    with pytest.raises(ValueError, match=r"expected \(H, W, C\) or \(B, H, W, C\)"):
        psnr(torch.rand(8, 8), torch.rand(8, 8))
    with pytest.raises(TypeError, match="expected torch tensors"):
        psnr(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))
