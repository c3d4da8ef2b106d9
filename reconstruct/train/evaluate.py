"""Evaluation on a scene's held-out views: PSNR / SSIM (scikit-image convention) / LPIPS where
weights were given, per view and averaged over the seen and the unseen views."""

from __future__ import annotations

import numpy as np
import torch

from ..avatar.model import AvatarModel
from ..data.scene import Scene
from ..metrics import psnr, ssim
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
def evaluate_views(model: AvatarModel, canon, scene: Scene, transforms_of, background: torch.Tensor,
                   *, lpips=None, views=None) -> tuple[list[dict], dict]:
    """``transforms_of(frame_index)`` gives the (J,4,4) bone transforms of a frame's pose; ``canon``
    is the CanonicalGaussians, or a function of the frame index giving them (pose-dependent
    Gaussians of Stage II)."""
    rows = []
    device = background.device
    canon_of = canon if callable(canon) else (lambda _i: canon)
    for v in (scene.eval_views if views is None else views):
        posed = model.pose(canon_of(v.frame_index), transforms_of(v.frame_index))
        r = render_avatar(posed, v.camera, background, normals=False)
        gt = torch.as_tensor(v.image, device=device) + (1 - torch.as_tensor(v.mask, device=device)[..., None]) * background
        pred = r.rgb.clamp(0, 1)
        row = {"view": v.camera.name, "frame": v.frame_index, "azimuth_deg": v.azimuth_deg, "seen": v.seen,
               "psnr": float(psnr(pred, gt)), "ssim": float(ssim(pred, gt)), "lpips": None}
        if lpips is not None:
            row["lpips"] = float(lpips(pred[None], gt[None]))
        rows.append(row)
    return rows, summarize(rows)
