"""Evaluation on a scene's held-out views: PSNR / SSIM (scikit-image convention) / LPIPS where
weights were given, per view and averaged over the seen and the unseen views; on views that carry
front-leak information (the unseen views of synthetic scenes) the front-leak ("tattoo") score of
``reconstruct.metrics.front_leak``, per view and as ``front_leak`` (region-weighted mean)."""

from __future__ import annotations

import math

import numpy as np
import torch

from ..avatar.state import AvatarState
from ..data.scene import Scene
from ..metrics import psnr, ssim
from ..metrics.front_leak import front_leak, front_leak_mean
from .render import render_avatar


def summarize(rows: list[dict]) -> dict:
    out = {}
    for group, pick in (("seen", True), ("unseen", False)):
        sel = [r for r in rows if r["seen"] == pick]
        for key in ("psnr", "ssim", "lpips"):
            vals = [r[key] for r in sel if r.get(key) is not None]
            out[f"{group}_{key}"] = float(np.mean(vals)) if vals else None
    return out


@torch.no_grad()
def evaluate_views(state: AvatarState, scene: Scene, background: torch.Tensor, *, lpips=None,
                   views=None) -> tuple[list[dict], dict]:
    """Renders the avatar ``state`` posed at each view's frame (with its Stage II pose-dependent
    Gaussians where it has them) and compares it with the view's ground truth."""
    rows = []
    device = background.device
    leak_renders, leak_views = [], []
    for v in (scene.eval_views if views is None else views):
        posed = state.posed(v.frame_index)
        r = render_avatar(posed, v.camera, background, normals=False)
        gt = torch.as_tensor(v.image, device=device) + (1 - torch.as_tensor(v.mask, device=device)[..., None]) * background
        pred = r.rgb.clamp(0, 1)
        row = {"view": v.camera.name, "frame": v.frame_index, "azimuth_deg": v.azimuth_deg, "seen": v.seen,
               "psnr": float(psnr(pred, gt)), "ssim": float(ssim(pred, gt)), "lpips": None}
        if lpips is not None:
            row["lpips"] = float(lpips(pred[None], gt[None]))
        if getattr(v, "front_leak", None) is not None:  # synthetic scenes' unseen views (front-only details)
            image = pred.cpu().numpy()
            leak = front_leak(image, v)
            row["front_leak"] = None if math.isnan(leak) else leak
            leak_renders.append(image)
            leak_views.append(v)
        rows.append(row)
    summary = summarize(rows)
    if leak_views:
        leak = front_leak_mean(leak_renders, leak_views)
        summary["front_leak"] = None if math.isnan(leak) else leak
    return rows, summary
