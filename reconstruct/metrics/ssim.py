"""Structural similarity (Wang et al. 2004) in torch: evaluation metric and training loss.

Images are channels-last, ``(H, W, C)`` or ``(B, H, W, C)``; each channel is compared on its
own and the SSIM map is averaged over pixels and channels.

Two border treatments share the same Gaussian window and formula:

- ``padding="valid"`` (default, for evaluation) reproduces scikit-image's
  ``structural_similarity(im1, im2, gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, data_range=1.0, channel_axis=-1)``. skimage filters with
  ``scipy.ndimage.gaussian_filter(mode="reflect", truncate=3.5)`` (radius
  ``int(3.5 * sigma + 0.5)``, so 11 taps for sigma 1.5) and then averages the SSIM map after
  cropping ``(win_size - 1) // 2`` pixels from every border. The cropped region never reads the
  padding, so it equals the map of an unpadded ("valid") convolution, which is what we compute.
  The match holds when ``window_size == 2 * int(3.5 * sigma + 0.5) + 1`` (true for 11 / 1.5).
- ``padding="same"`` is the training loss of 3DGS and GaussianAvatar: the same window applied
  with zero padding of ``window_size // 2``, and the map averaged over all ``H x W`` pixels
  (border pixels included). Use ``1 - ssim(pred, gt, padding="same")`` as that loss.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .psnr import image_pair_as_batch, reduce_per_image

K1 = 0.01
K2 = 0.03
PADDINGS = ("valid", "same")


def gaussian_window_1d(window_size: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Normalised 1-D Gaussian taps ``exp(-x^2 / (2 sigma^2))``, ``x = -r..r``, built in float64."""
    radius = window_size // 2
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    taps = torch.exp(-0.5 * (x / sigma) ** 2)
    return (taps / taps.sum()).to(dtype=dtype, device=device)


def _blur(planes: torch.Tensor, taps: torch.Tensor, pad: int) -> torch.Tensor:
    """Separable Gaussian filter of each channel of ``(B, N, H, W)``; ``pad`` zeros on each side.

    A depthwise (grouped) convolution: several times faster on CPU than ``(B*N, 1, H, W)``.
    """
    n, k = planes.shape[1], taps.numel()
    planes = F.conv2d(planes, taps.view(1, 1, 1, k).expand(n, 1, 1, k), padding=(0, pad), groups=n)
    return F.conv2d(planes, taps.view(1, 1, k, 1).expand(n, 1, k, 1), padding=(pad, 0), groups=n)


def ssim(
    pred: torch.Tensor,
    target: torch.Tensor,
    *,
    window_size: int = 11,
    sigma: float = 1.5,
    data_range: float = 1.0,
    reduction: str = "mean",
    return_map: bool = False,
    padding: str = "valid",
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Mean SSIM of channels-last images ``(H, W, C)`` or ``(B, H, W, C)``; differentiable.

    Constants ``C1 = (0.01 data_range)^2``, ``C2 = (0.03 data_range)^2``; population
    (co)variances under a ``window_size`` Gaussian window of std ``sigma``. See the module
    docstring for ``padding``: ``"valid"`` (default) matches scikit-image for evaluation,
    ``"same"`` is the 3DGS / GaussianAvatar training loss.

    ``reduction="mean"`` returns a scalar (mean over batch, pixels and channels); ``"none"``
    returns one value per image, ``(B,)`` (a scalar for an unbatched input). With
    ``return_map=True`` also returns the SSIM map, channels-last like the input, of spatial size
    ``(H - window_size + 1, W - window_size + 1)`` for ``"valid"`` and ``(H, W)`` for ``"same"``.
    Computation stays in the input dtype.
    """
    pred, target, batched = image_pair_as_batch(pred, target, "ssim")
    if window_size < 1 or window_size % 2 == 0:
        raise ValueError(f"ssim: window_size must be a positive odd integer, found {window_size}")
    if sigma <= 0 or data_range <= 0:
        raise ValueError(f"ssim: sigma and data_range must be positive, found sigma={sigma}, data_range={data_range}")
    if padding not in PADDINGS:
        raise ValueError(f"ssim: padding must be one of {PADDINGS}, found {padding!r}")
    h, w = pred.shape[1:3]
    if padding == "valid" and (h < window_size or w < window_size):
        raise ValueError(
            f"ssim: image {h}x{w} is smaller than the {window_size}x{window_size} window (padding='valid')"
        )

    # (B, H, W, C) -> (B, C, H, W), then filter x, y, x^2, y^2, xy in one depthwise pass.
    x = pred.permute(0, 3, 1, 2)
    y = target.permute(0, 3, 1, 2)
    taps = gaussian_window_1d(window_size, sigma, pred.dtype, pred.device)
    pad = window_size // 2 if padding == "same" else 0
    mu_x, mu_y, e_xx, e_yy, e_xy = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), taps, pad).chunk(5, dim=1)
    var_x = e_xx - mu_x * mu_x
    var_y = e_yy - mu_y * mu_y
    cov_xy = e_xy - mu_x * mu_y

    c1 = (K1 * data_range) ** 2
    c2 = (K2 * data_range) ** 2
    num = (2 * mu_x * mu_y + c1) * (2 * cov_xy + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2)
    ssim_map = (num / den).permute(0, 2, 3, 1)

    value = reduce_per_image(ssim_map.mean(dim=(1, 2, 3)), reduction, batched, "ssim")
    if not return_map:
        return value
    return value, ssim_map if batched else ssim_map[0]
