"""Evaluation on a scene's held-out views: PSNR / SSIM (scikit-image convention) / LPIPS where
weights were given, per view and averaged over the seen and the unseen views; on views that carry
front-leak information (the unseen views of synthetic scenes) the front-leak ("tattoo") score of
``reconstruct.metrics.front_leak``, per view and as ``front_leak`` (region-weighted mean).

Coverage, per view and averaged per group:
* ``hole_fraction``: the share of ground-truth foreground pixels at least ``HOLE_INSET`` pixels
  inside the mask (every pixel within that Chebyshev distance is foreground) whose rendered alpha
  is below ``HOLE_ALPHA`` -- the background showing through the body;
* ``alpha_iou``: intersection over union of rendered alpha > 0.5 and the mask.

``scale``: every view is rendered at ``scale`` x its resolution (the camera's intrinsics scaled)
and compared with its ground truth upsampled bilinearly (the mask thresholded at 0.5 after
upsampling): a zoom that shows gaps between Gaussians which the scene's own resolution hides.
``scale=1`` keeps the scene's own images. Front leak is scored on the render averaged back down to
the scene's resolution.

The avatar is decoded and posed once per video frame that the views use (views share frames).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from ..avatar.state import AvatarState
from ..data.scene import Scene
from ..metrics import psnr, ssim
from ..metrics.front_leak import front_leak, front_leak_mean
from .render import render_avatar

HOLE_INSET = 2  # pixels inside the mask
HOLE_ALPHA = 0.9
IOU_ALPHA = 0.5
KEYS = ("psnr", "ssim", "lpips", "hole_fraction", "alpha_iou")


def summarize(rows: list[dict]) -> dict:
    out = {}
    for group, pick in (("seen", True), ("unseen", False)):
        sel = [r for r in rows if r["seen"] == pick]
        for key in KEYS:
            vals = [r[key] for r in sel if r.get(key) is not None]
            out[f"{group}_{key}"] = float(np.mean(vals)) if vals else None
    return out


def inner_mask(mask: torch.Tensor, inset: int = HOLE_INSET) -> torch.Tensor:
    """Pixels of the boolean (H,W) ``mask`` whose whole (2 inset + 1)^2 neighbourhood is in the mask."""
    m = mask.float()[None, None]
    eroded = -F.max_pool2d(-m, 2 * inset + 1, stride=1, padding=inset)
    # max_pool pads with -inf, i.e. treats the outside of the image as foreground: the image border
    # is not background
    return eroded[0, 0] > 0.5


def hole_fraction(alpha: torch.Tensor, mask: torch.Tensor, inset: int = HOLE_INSET,
                  threshold: float = HOLE_ALPHA) -> float | None:
    """Share of the pixels ``inset`` px inside the boolean ``mask`` where ``alpha`` < ``threshold``
    (None when no pixel is that far inside)."""
    inner = inner_mask(mask, inset)
    n = int(inner.sum())
    if n == 0:
        return None
    return float((alpha[inner] < threshold).sum()) / n


def alpha_iou(alpha: torch.Tensor, mask: torch.Tensor, threshold: float = IOU_ALPHA) -> float | None:
    a = alpha > threshold
    union = int((a | mask).sum())
    return None if union == 0 else float((a & mask).sum()) / union


def upsample(image: np.ndarray, scale: int, device) -> torch.Tensor:
    """(H,W[,C]) float image -> (sH,sW[,C]) tensor, bilinear (the identity for scale 1)."""
    t = torch.as_tensor(image, dtype=torch.float32, device=device)
    if scale == 1:
        return t
    x = t[None, None] if t.ndim == 2 else t.permute(2, 0, 1)[None]
    y = F.interpolate(x, scale_factor=scale, mode="bilinear", align_corners=False)
    return y[0, 0] if t.ndim == 2 else y[0].permute(1, 2, 0)


@torch.no_grad()
def rendered_views(state: AvatarState, scene: Scene, background: torch.Tensor, *, views=None, scale: int = 1):
    """Yields (view, render, ground truth over ``background``, boolean mask) for each evaluation
    view (``scene.eval_views`` unless ``views``): the avatar ``state`` posed at the view's frame
    (with its Stage II pose-dependent Gaussians where it has them), rendered at ``scale`` x the
    view's resolution, the ground truth upsampled to it."""
    scale = int(scale)
    if scale < 1:
        raise ValueError(f"evaluation scale must be a positive integer, found {scale}")
    device = background.device
    posed_at: dict[int, object] = {}
    for v in (scene.eval_views if views is None else views):
        if v.frame_index not in posed_at:
            posed_at[v.frame_index] = state.posed(v.frame_index)
        cam = v.camera if scale == 1 else v.camera.scaled(v.camera.width * scale, v.camera.height * scale)
        r = render_avatar(posed_at[v.frame_index], cam, background, normals=False)
        mask_f = upsample(v.mask, scale, device)
        gt = upsample(v.image, scale, device) + (1 - mask_f[..., None]) * background
        yield v, r, gt, mask_f > 0.5


@torch.no_grad()
def evaluate_views(state: AvatarState, scene: Scene, background: torch.Tensor, *, lpips=None,
                   views=None, scale: int = 1) -> tuple[list[dict], dict]:
    """Renders the avatar ``state`` at each view (``rendered_views``) and compares it with the
    view's ground truth."""
    scale = int(scale)
    rows = []
    leak_renders, leak_views = [], []
    for v, r, gt, mask in rendered_views(state, scene, background, views=views, scale=scale):
        alpha = r.alpha
        pred = r.rgb.clamp(0, 1)
        row = {"view": v.camera.name, "frame": v.frame_index, "azimuth_deg": v.azimuth_deg, "seen": v.seen,
               "psnr": float(psnr(pred, gt)), "ssim": float(ssim(pred, gt)), "lpips": None,
               "hole_fraction": hole_fraction(alpha, mask), "alpha_iou": alpha_iou(alpha, mask)}
        if lpips is not None:
            row["lpips"] = float(lpips(pred[None], gt[None]))
        if getattr(v, "front_leak", None) is not None:  # synthetic scenes' unseen views (front-only details)
            small = pred if scale == 1 else F.avg_pool2d(pred.permute(2, 0, 1)[None], scale)[0].permute(1, 2, 0)
            image = small.cpu().numpy()
            leak = front_leak(image, v)
            row["front_leak"] = None if math.isnan(leak) else leak
            leak_renders.append(image)
            leak_views.append(v)
        rows.append(row)
    summary = summarize(rows)
    if scale != 1:
        summary["scale"] = scale
    if leak_views:
        leak = front_leak_mean(leak_renders, leak_views)
        summary["front_leak"] = None if math.isnan(leak) else leak
    return rows, summary
