"""Helpers of the stability suite (imported by its tests; not a test module)."""

from __future__ import annotations

import json
import math
import os

import torch


def grad_norm(tensors) -> float:
    """Euclidean norm of all the gradients of ``tensors`` together (0 where none)."""
    return math.sqrt(sum(float((t.grad.double() ** 2).sum()) for t in tensors if t.grad is not None))


def all_finite(tensors) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in tensors if t is not None)


def record(case: str, **figures) -> None:
    """Append the figures of a case to ``$STABILITY_REPORT`` (JSON lines) when it is set: the
    source of the table in docs/stability.md. Also printed (``pytest -s`` shows them)."""
    row = {"case": case, **{k: (float(v) if isinstance(v, (int, float)) else v) for k, v in figures.items()}}
    print("stability:", json.dumps(row))
    path = os.environ.get("STABILITY_REPORT")
    if path:
        with open(path, "a") as f:
            f.write(json.dumps(row) + "\n")


def stage1_loss(model, transforms, camera, target_rgb, target_normal=None, *, config=None, dtype=torch.float32,
                background=(0.0, 0.0, 0.0)):
    """The Stage I loss of the Trainer's given-view step (without LPIPS) for one view, in ``dtype``: the model
    and the inputs are used as they are (convert them first). Returns (loss, terms, render)."""
    from reconstruct.train import losses as L
    from reconstruct.train.config import Stage1Config
    from reconstruct.train.render import render_avatar

    cfg = config or Stage1Config()
    bg = torch.tensor(background, dtype=dtype)
    canon = model.canonical()
    posed = model.pose(canon, transforms.to(dtype))
    r = render_avatar(posed, camera, bg, normals=target_normal is not None)
    terms = {"rgb": L.mse(r.rgb, target_rgb.to(dtype)), "ssim": L.ssim_loss(r.rgb, target_rgb.to(dtype)),
             "offset": L.mean_square(canon.offsets_raw), "scale": L.mean_square(canon.scales),
             "features": L.mean_square(canon.features)}
    weights = {"rgb": cfg.lambda_rgb, "ssim": cfg.lambda_ssim, "offset": cfg.lambda_offset,
               "scale": cfg.lambda_scale, "features": cfg.lambda_features}
    if target_normal is not None:
        terms["normal"] = L.mse(r.normal, target_normal.to(dtype))
        weights["normal"] = cfg.lambda_normal
    loss = sum(weights[k] * v for k, v in terms.items())
    return loss, terms, r
