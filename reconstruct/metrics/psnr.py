"""Peak signal-to-noise ratio, plus the image-pair checks shared by the metrics.

All metrics in this package take channels-last images: ``(H, W, C)`` or ``(B, H, W, C)``.
A 3-D tensor is always one image (a grayscale image needs ``C = 1``).
"""

from __future__ import annotations

import torch

REDUCTIONS = ("mean", "none")


def image_pair_as_batch(
    pred: torch.Tensor, target: torch.Tensor, metric: str
) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Check a pair of channels-last images and return them as ``(B, H, W, C)`` plus ``batched``.

    ``batched`` is False when the inputs were single ``(H, W, C)`` images.
    """
    if not isinstance(pred, torch.Tensor) or not isinstance(target, torch.Tensor):
        raise TypeError(f"{metric}: expected torch tensors, found {type(pred).__name__} and {type(target).__name__}")
    if pred.shape != target.shape:
        raise ValueError(f"{metric}: pred and target shapes differ: {tuple(pred.shape)} vs {tuple(target.shape)}")
    if pred.dim() not in (3, 4):
        raise ValueError(
            f"{metric}: expected (H, W, C) or (B, H, W, C) channels-last images, found shape {tuple(pred.shape)}"
        )
    if not pred.is_floating_point() or not target.is_floating_point():
        raise TypeError(f"{metric}: expected floating-point images, found {pred.dtype} and {target.dtype}")
    batched = pred.dim() == 4
    if not batched:
        pred, target = pred.unsqueeze(0), target.unsqueeze(0)
    return pred, target, batched


def reduce_per_image(values: torch.Tensor, reduction: str, batched: bool, metric: str) -> torch.Tensor:
    """Reduce per-image values ``(B,)``: ``"mean"`` -> scalar; ``"none"`` -> ``(B,)`` (scalar if unbatched)."""
    if reduction == "mean":
        return values.mean()
    if reduction == "none":
        return values if batched else values[0]
    raise ValueError(f"{metric}: reduction must be one of {REDUCTIONS}, found {reduction!r}")


def psnr(
    pred: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None = None,
    data_range: float = 1.0,
    *,
    reduction: str = "mean",
) -> torch.Tensor:
    """PSNR in dB, ``10 log10(data_range^2 / MSE)``, computed per image.

    Images are channels-last ``(H, W, C)`` or ``(B, H, W, C)``. With ``reduction="mean"`` the
    per-image PSNRs are averaged (the usual protocol for a test set); ``"none"`` returns them.

    ``mask`` (optional) has the image shape without the channel axis, ``(H, W)`` / ``(B, H, W)``,
    or with a trailing 1, ``(H, W, 1)`` / ``(B, H, W, 1)``; bool or {0, 1} float. With a mask the
    MSE is taken over the masked pixels only (all channels of each masked pixel), not over the
    whole frame; a float mask acts as per-pixel weights. An image whose mask is empty raises.
    Identical images give ``+inf``.
    """
    pred, target, batched = image_pair_as_batch(pred, target, "psnr")
    if data_range <= 0:
        raise ValueError(f"psnr: data_range must be positive, found {data_range}")
    sq_err = (pred - target).square()
    if mask is None:
        mse = sq_err.mean(dim=(1, 2, 3))
    else:
        weights = _mask_as_weights(mask, pred.shape, batched).to(sq_err.dtype)
        count = weights.sum(dim=(1, 2, 3))
        empty = (count == 0).nonzero().flatten().tolist()
        if empty:
            raise ValueError(f"psnr: mask is empty for image(s) {empty}; the masked MSE is undefined")
        mse = (sq_err * weights).sum(dim=(1, 2, 3)) / (count * pred.shape[-1])
    values = 10.0 * torch.log10(data_range**2 / mse)
    return reduce_per_image(values, reduction, batched, "psnr")


def _mask_as_weights(mask: torch.Tensor, image_shape: torch.Size, batched: bool) -> torch.Tensor:
    """Return ``mask`` as ``(B, H, W, 1)`` weights after checking its shape against the images."""
    b, h, w, _ = image_shape
    pixel_shape = (b, h, w) if batched else (h, w)
    if tuple(mask.shape) not in (pixel_shape, pixel_shape + (1,)):
        raise ValueError(
            f"psnr: mask shape {tuple(mask.shape)} does not match the images; expected {pixel_shape} "
            f"or {pixel_shape + (1,)}"
        )
    return mask.reshape(b, h, w, 1)
