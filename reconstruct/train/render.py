"""Rendering an avatar for training and evaluation: RGB and camera-space normals in one pass."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..avatar.model import PosedGaussians
from ..camera import Camera
from ..raster import rasterization


@dataclass
class AvatarRender:
    rgb: torch.Tensor  # (H,W,3) over the background
    normal: torch.Tensor | None  # (H,W,3) alpha-weighted camera-space normals (0 background)
    alpha: torch.Tensor  # (H,W)
    depth: torch.Tensor  # (H,W)
    first_hit: torch.Tensor | None  # (H,W) Gaussian ids or -1


def render_avatar(posed: PosedGaussians, camera: Camera, background: torch.Tensor, *, normals: bool = True,
                  first_hit: bool = False, hit_threshold: float = 0.5, backend: str = "auto") -> AvatarRender:
    feats = posed.colors
    bg = background
    if normals:
        R = torch.as_tensor(camera.R, dtype=posed.normals.dtype, device=posed.normals.device)
        feats = torch.cat([posed.colors, posed.normals @ R.T], dim=1)
        bg = torch.cat([background, torch.zeros(3, dtype=background.dtype, device=background.device)])
    out = rasterization(posed.means, posed.quats, posed.scales, posed.opacities, feats, camera, background=bg,
                        backend=backend, return_first_hit=first_hit, hit_threshold=hit_threshold)
    return AvatarRender(out.image[..., :3], out.image[..., 3:6] if normals else None, out.alpha, out.depth,
                        out.first_hit)


def mask_box(mask: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the mask's nonzero pixels grown by ``margin``, clipped to the image."""
    ys, xs = np.nonzero(mask > 0)
    if len(xs) == 0:
        raise ValueError("the mask is empty")
    H, W = mask.shape
    return (max(0, int(xs.min()) - margin), max(0, int(ys.min()) - margin),
            min(W, int(xs.max()) + 1 + margin), min(H, int(ys.max()) + 1 + margin))


def crop_camera(camera: Camera, box: tuple[int, int, int, int]) -> Camera:
    """The camera that renders exactly the pixels ``box`` = (x0, y0, x1, y1) of ``camera``."""
    x0, y0, x1, y1 = box
    K = camera.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K, camera.R, camera.t, x1 - x0, y1 - y0, camera.near, camera.far, camera.name, dict(camera.meta))
