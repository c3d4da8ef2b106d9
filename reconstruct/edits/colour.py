"""RGB <-> HSV in torch, differentiable and safe at grey (no division by zero)."""

from __future__ import annotations

import torch

EPS = 1e-8


def rgb_to_hsv(rgb: torch.Tensor) -> torch.Tensor:
    """(..., 3) RGB in [0,1] -> (..., 3) HSV, hue in [0,1)."""
    r, g, b = rgb.unbind(-1)
    maxc, which = rgb.max(-1)
    minc = rgb.min(-1).values
    delta = maxc - minc
    d = delta.clamp_min(EPS)
    h = torch.where(which == 0, torch.remainder((g - b) / d, 6.0),
                    torch.where(which == 1, (b - r) / d + 2.0, (r - g) / d + 4.0)) / 6.0
    h = torch.where(delta > EPS, h, torch.zeros_like(h))
    s = delta / maxc.clamp_min(EPS)
    return torch.stack([h, s, maxc], -1)


def hsv_to_rgb(hsv: torch.Tensor) -> torch.Tensor:
    h, s, v = hsv.unbind(-1)
    out = []
    for n in (5.0, 3.0, 1.0):
        k = torch.remainder(n + 6.0 * h, 6.0)
        out.append(v - v * s * torch.clamp(torch.minimum(k, 4.0 - k), 0.0, 1.0))
    return torch.stack(out, -1)


def recolour(rgb: torch.Tensor, hue_deg: float, saturation: float, value: float) -> torch.Tensor:
    """Hue rotated by ``hue_deg``, saturation and value scaled (clamped to [0,1])."""
    h, s, v = rgb_to_hsv(rgb).unbind(-1)
    h = torch.remainder(h + hue_deg / 360.0, 1.0)
    return hsv_to_rgb(torch.stack([h, (s * saturation).clamp(0, 1), (v * value).clamp(0, 1)], -1))
