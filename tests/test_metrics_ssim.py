"""SSIM: agreement with scikit-image (evaluation mode), the 3DGS training variant, gradients."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
import skimage.data
import torch
import torch.nn.functional as F
from skimage.filters import gaussian as sk_gaussian
from skimage.metrics import structural_similarity

from reconstruct.metrics import ssim

# Tolerance of the task (float32) and a much tighter one where both sides compute in float64.
TOLERANCE = {np.float32: 1e-4, np.float64: 1e-10}


def skimage_ssim(a: np.ndarray, b: np.ndarray, **kwargs) -> float:
    """The evaluation reference: Wang et al.'s settings in scikit-image."""
    kwargs = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False, "data_range": 1.0, **kwargs}
    return float(structural_similarity(a, b, channel_axis=-1, **kwargs))


def synthetic_scene(h: int = 120, w: int = 150, seed: int = 0) -> np.ndarray:
    """A "real-looking" RGB image: smooth gradients, a textured region and hard edges, in [0, 1]."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    img = np.stack([0.2 + 0.6 * xx, 0.3 + 0.5 * yy, 0.5 + 0.3 * np.sin(3 * xx + 2 * yy)], axis=-1)
    texture = 0.15 * np.sin(40 * xx)[..., None] * np.cos(35 * yy)[..., None] + 0.05 * rng.standard_normal((h, w, 3))
    img[h // 2 :, : w // 2] += texture[h // 2 :, : w // 2]
    disk = (yy - 0.3) ** 2 + (xx - 0.7) ** 2 < 0.04
    img[disk] = (0.9, 0.1, 0.2)
    img[int(0.7 * h) : int(0.9 * h), int(0.6 * w) : int(0.95 * w)] = (0.05, 0.05, 0.1)
    return np.clip(img, 0, 1)


def degrade(img: np.ndarray, seed: int = 1) -> np.ndarray:
    """Blur, then add noise and a small brightness shift."""
    rng = np.random.default_rng(seed)
    blurred = sk_gaussian(img, sigma=1.2, channel_axis=-1)
    return np.clip(blurred + 0.03 * rng.standard_normal(img.shape) + 0.02, 0, 1)


@lru_cache(maxsize=None)
def image_pairs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Float64 image pairs by kind; skimage.data images ship inside the wheel (no download)."""
    rng = np.random.default_rng(0)
    scene = synthetic_scene()
    astronaut = skimage.data.astronaut()[:256, 128:384] / 255.0
    chelsea = skimage.data.chelsea() / 255.0
    coffee = skimage.data.coffee()[::2, ::2] / 255.0
    return {
        "random_uniform": (rng.random((64, 80, 3)), rng.random((64, 80, 3))),
        "synthetic_degraded": (scene, degrade(scene)),
        "astronaut_degraded": (astronaut, degrade(astronaut)),
        "chelsea_noise": (chelsea, np.clip(chelsea + 0.1 * rng.standard_normal(chelsea.shape), 0, 1)),
        "coffee_blur": (coffee, sk_gaussian(coffee, sigma=2.0, channel_axis=-1)),
    }


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("kind", list(image_pairs()))
def test_matches_skimage(kind, dtype):
    a, b = (img.astype(dtype) for img in image_pairs()[kind])
    ours = ssim(torch.from_numpy(a), torch.from_numpy(b)).item()
    assert abs(ours - skimage_ssim(a, b)) < TOLERANCE[dtype]


def test_map_matches_skimage_cropped_map():
    a, b = image_pairs()["synthetic_degraded"]
    _, ours = ssim(torch.from_numpy(a), torch.from_numpy(b), return_map=True)
    assert ours.shape == (a.shape[0] - 10, a.shape[1] - 10, 3)
    for c in range(3):
        _, full = structural_similarity(
            a[..., c], b[..., c], gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
            data_range=1.0, full=True,
        )
        np.testing.assert_allclose(ours[..., c].numpy(), full[5:-5, 5:-5], atol=1e-12)


def test_other_sigma_and_data_range_match_skimage():
    a, b = image_pairs()["synthetic_degraded"]
    # skimage's window for sigma=1.0 has radius int(3.5 * 1.0 + 0.5) = 4, i.e. 9 taps.
    ours = ssim(torch.from_numpy(a), torch.from_numpy(b), window_size=9, sigma=1.0).item()
    assert ours == pytest.approx(skimage_ssim(a, b, sigma=1.0), abs=1e-10)
    ours = ssim(torch.from_numpy(a * 255), torch.from_numpy(b * 255), data_range=255.0).item()
    assert ours == pytest.approx(skimage_ssim(a * 255, b * 255, data_range=255.0), abs=1e-10)


def test_grayscale_single_channel_matches_skimage():
    a, b = (img[..., 0] for img in image_pairs()["synthetic_degraded"])
    ours = ssim(torch.from_numpy(a[..., None]), torch.from_numpy(b[..., None])).item()
    ref = structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0)
    assert ours == pytest.approx(ref, abs=1e-10)


def test_batch_and_reduction():
    a, b = image_pairs()["synthetic_degraded"]
    c = synthetic_scene(seed=3)[::-1]
    d = degrade(c, seed=4)
    pred = torch.from_numpy(np.stack([a, c]))
    target = torch.from_numpy(np.stack([b, d]))
    per_image = ssim(pred, target, reduction="none")
    assert per_image.shape == (2,)
    assert per_image[0].item() == pytest.approx(skimage_ssim(a, b), abs=1e-10)
    assert per_image[1].item() == pytest.approx(skimage_ssim(c, d), abs=1e-10)
    assert ssim(pred, target).item() == pytest.approx(per_image.mean().item(), abs=1e-12)
    assert ssim(pred[0], target[0], reduction="none").shape == ()


@pytest.mark.parametrize("padding", ["valid", "same"])
def test_identical_images_give_one(padding):
    x = torch.from_numpy(image_pairs()["synthetic_degraded"][0].astype(np.float32))
    assert ssim(x, x, padding=padding).item() == pytest.approx(1.0, abs=1e-6)


def reference_3dgs_ssim(img1: torch.Tensor, img2: torch.Tensor, window_size: int = 11) -> torch.Tensor:
    """The 3DGS / GaussianAvatar loss (utils/loss_utils.py) on (C, H, W): 2-D window, zero padding."""
    x = torch.arange(window_size, dtype=torch.float64) - window_size // 2
    gauss = torch.exp(-(x**2) / (2 * 1.5**2))
    gauss = (gauss / gauss.sum())[:, None]
    channel = img1.shape[0]
    window = (gauss @ gauss.T).expand(channel, 1, window_size, window_size).contiguous()

    def conv(t):
        return F.conv2d(t[None], window, padding=window_size // 2, groups=channel)[0]

    mu1, mu2 = conv(img1), conv(img2)
    sigma1_sq = conv(img1 * img1) - mu1.pow(2)
    sigma2_sq = conv(img2 * img2) - mu2.pow(2)
    sigma12 = conv(img1 * img2) - mu1 * mu2
    c1, c2 = 0.01**2, 0.03**2
    ssim_map = ((2 * mu1 * mu2 + c1) * (2 * sigma12 + c2)) / (
        (mu1.pow(2) + mu2.pow(2) + c1) * (sigma1_sq + sigma2_sq + c2)
    )
    return ssim_map.mean()


def test_same_padding_matches_3dgs_training_loss():
    a, b = (torch.from_numpy(img) for img in image_pairs()["synthetic_degraded"])
    ours, ssim_map = ssim(a, b, padding="same", return_map=True)
    assert ssim_map.shape == a.shape
    expected = reference_3dgs_ssim(a.permute(2, 0, 1), b.permute(2, 0, 1))
    assert ours.item() == pytest.approx(expected.item(), abs=1e-12)


@pytest.mark.parametrize(
    ("shape", "kwargs"),
    [
        ((1, 13, 14, 2), {}),
        ((1, 9, 8, 2), {"padding": "same"}),
        ((2, 8, 9, 1), {"window_size": 5, "sigma": 1.0}),
    ],
)
def test_gradcheck(shape, kwargs):
    gen = torch.Generator().manual_seed(0)
    pred = torch.rand(shape, generator=gen, dtype=torch.float64, requires_grad=True)
    target = torch.rand(shape, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p, t: ssim(p, t, **kwargs), (pred, target))


def test_loss_gradient_decreases_loss():
    a, b = (torch.from_numpy(img.astype(np.float32)) for img in image_pairs()["synthetic_degraded"])
    pred = b.clone().requires_grad_(True)
    loss = 1 - ssim(pred, a, padding="same")
    loss.backward()
    with torch.no_grad():
        stepped = 1 - ssim(pred - 1e-1 * pred.grad / pred.grad.abs().max(), a, padding="same")
    assert stepped < loss


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"window_size": 10}, "window_size must be a positive odd integer"),
        ({"sigma": 0.0}, "sigma and data_range must be positive"),
        ({"padding": "reflect"}, "padding must be one of"),
        ({"reduction": "sum"}, "reduction must be one of"),
        ({"window_size": 21}, "smaller than the 21x21 window"),
    ],
)
def test_errors(kwargs, message):
    x = torch.rand(16, 20, 3)
    with pytest.raises(ValueError, match=message):
        ssim(x, x, **kwargs)
