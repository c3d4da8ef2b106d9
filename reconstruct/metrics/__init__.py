"""Image metrics for evaluation and training: PSNR, SSIM and LPIPS (channels-last images)."""

from .lpips import LPIPS, LPIPSConfig, LPIPSWeightsError, load_lpips_or_none
from .psnr import psnr
from .ssim import ssim

__all__ = ["LPIPS", "LPIPSConfig", "LPIPSWeightsError", "load_lpips_or_none", "psnr", "ssim"]
