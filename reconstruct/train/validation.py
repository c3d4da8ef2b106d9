"""Seen-view validation on the video itself, for scenes without ground truth from other views (a
person's own footage): every k-th frame is held out of training and the avatar is compared with it
at its camera and pose -- PSNR and SSIM over the frame's body box (the person composited on the
training background) and the IoU of the rendered alpha with the person mask. A scene of one frame
has nothing to hold out: the training view's fit is reported instead (``val_kind``)."""

from __future__ import annotations

import numpy as np
import torch

from ..avatar.state import AvatarState
from ..data.scene import Scene
from ..metrics import psnr, ssim
from ..metrics.coverage import alpha_iou
from .render import crop_camera, mask_box, render_avatar

DEFAULT_HOLDOUT = 8  # every 8th frame of a scene without evaluation views


def holdout_frames(num_frames: int, every: int) -> list[int]:
    """Frames held out of training: every ``every``-th, starting from the middle of the first
    interval (frame every // 2), never all of them; [] for ``every`` 0 or fewer than 2 frames."""
    if every < 0:
        raise ValueError(f"holdout must be 0 (off) or a positive frame interval, found {every}")
    if every == 0 or num_frames < 2:
        return []
    held = list(range(every // 2, num_frames, max(every, 2)))
    return held if len(held) < num_frames else held[:-1]


def resolve_holdout(scene: Scene, holdout: int | None) -> int:
    """The holdout interval a run uses: as given, or -- ``None`` -- ``DEFAULT_HOLDOUT`` for a scene
    without evaluation views and 0 for one that has them (synthetic and multi-view datasets)."""
    if holdout is None:
        return 0 if scene.eval_views else DEFAULT_HOLDOUT
    return int(holdout)


@torch.no_grad()
def validate_frames(state: AvatarState, scene: Scene, frames: list[int], background: torch.Tensor,
                    margin: int = 8) -> tuple[list[dict], dict]:
    """Rows (one per frame: psnr, ssim, alpha_iou) and their means (``val_psnr``, ``val_ssim``,
    ``val_alpha_iou``)."""
    rows = []
    device = background.device
    for i in frames:
        f = scene.frames[i]
        box = mask_box(f.mask, margin)
        x0, y0, x1, y1 = box
        r = render_avatar(state.posed(i), crop_camera(f.camera, box), background, normals=False)
        mask = torch.as_tensor(np.ascontiguousarray(f.mask[y0:y1, x0:x1]), dtype=torch.float32, device=device)
        image = torch.as_tensor(np.ascontiguousarray(f.image[y0:y1, x0:x1]), dtype=torch.float32, device=device)
        gt = image + (1 - mask[..., None]) * background  # the person is over black in the frame
        pred = r.rgb.clamp(0, 1)
        rows.append({"frame": i, "psnr": float(psnr(pred, gt)), "ssim": float(ssim(pred, gt)),
                     "alpha_iou": alpha_iou(r.alpha, mask)})
    summary = {f"val_{k}": (float(np.mean([r[k] for r in rows])) if rows else None)
               for k in ("psnr", "ssim", "alpha_iou")}
    return rows, summary
