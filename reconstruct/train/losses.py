"""Stage I losses (paper Eq. 11): image terms and the regularisers.

The paper writes the regularisers as Frobenius norms; the weights of its Appendix A.1.3 are those
of GaussianAvatar's code, where each regulariser is the *mean* of squares (the Frobenius norm
squared over the element count). We use that normalisation so the published weights keep their
meaning: with the plain norm, lambda_dx = 0.85 on 10^4..10^5 offsets would swamp the image terms.
"""

from __future__ import annotations

import torch

from ..metrics.ssim import ssim


def mse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return ((pred - target) ** 2).mean()


def ssim_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - SSIM with the same-padded 11x11 sigma 1.5 window of 3DGS/GaussianAvatar training."""
    return 1.0 - ssim(pred, target, padding="same")


def mean_square(x: torch.Tensor) -> torch.Tensor:
    """The regulariser ||x||_F^2 / numel(x)."""
    return (x * x).mean()


def normal_deviation(normals: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Mean (1 - cos) between unit ``normals`` (N,3) and unit ``reference`` normals (N,3): 0 when
    they agree, 1 at a right angle, 2 flipped (the normal prior of frames without a normal map)."""
    return (1.0 - (normals * reference).sum(-1)).mean()
