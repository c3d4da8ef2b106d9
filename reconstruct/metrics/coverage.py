"""Coverage of the person by the rendered avatar: how well its alpha matches the mask."""

from __future__ import annotations

import torch


def alpha_iou(alpha: torch.Tensor, mask: torch.Tensor, threshold: float = 0.5) -> float:
    """Intersection over union of (rendered alpha > threshold) and (mask > 0.5), both (H,W); 1.0
    when both are empty."""
    a = alpha > threshold
    m = mask > 0.5
    union = int((a | m).sum())
    return 1.0 if union == 0 else int((a & m).sum()) / union
