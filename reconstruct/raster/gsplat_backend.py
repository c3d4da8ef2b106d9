"""gsplat's CUDA rasterizer as a backend (only where CUDA is present and gsplat's extension loads).

Same conventions as the CPU kernel: OpenCV camera (gsplat's own), pixel centres at +0.5,
eps2d low-pass, near plane, features composited as they are, expected depth ("RGB+ED").
gsplat's own rules differ from ours in details that matter only at the margins: its alpha
clamp is 0.999 (ours 0.99), its screen radius is 3.33 sigma per axis tightened by opacity, and
within a tile it evaluates every Gaussian of the tile (we evaluate a Gaussian within its 3-sigma
box only). For opacities below ~0.35 and no early termination the results agree to float32
rounding (see tests/test_raster_api.py, marked ``gpu``). First-hit ids are computed with this
project's projection and reference compositor on the same device.
"""

from __future__ import annotations

import functools

import torch
from torch import Tensor

from ..camera import Camera
from .projection import project_gaussians
from .reference import rasterize_reference


@functools.lru_cache(maxsize=1)
def is_available() -> bool:
    """True when CUDA is present and gsplat's CUDA extension can be loaded (no JIT failure)."""
    if not torch.cuda.is_available():
        return False
    try:
        from gsplat.cuda._backend import _C  # may attempt a JIT CUDA build
    except Exception:  # ImportError from a failed JIT build, missing `packaging`, ...
        return False
    return _C is not None


def rasterize_gsplat(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, features: Tensor,
                     background: Tensor, camera: Camera, *, eps2d: float, near: float,
                     return_first_hit: bool, hit_threshold: float):
    """Render with ``gsplat.rasterization``; returns (image, alpha, depth, first_hit, radii)."""
    import gsplat

    viewmat = torch.as_tensor(camera.viewmat, dtype=means.dtype, device=means.device)
    K = torch.as_tensor(camera.K, dtype=means.dtype, device=means.device)
    C = features.shape[1]
    renders, alphas, meta = gsplat.rasterization(
        means, quats, scales, opacities, features, viewmat[None], K[None], camera.width, camera.height,
        near_plane=near, far_plane=1e10, eps2d=eps2d, packed=False, tile_size=16,
        backgrounds=background[None], render_mode="RGB+ED", rasterize_mode="classic")
    image, depth, alpha = renders[0, ..., :C], renders[0, ..., C], alphas[0, ..., 0]
    radii = meta["radii"][0].amax(dim=-1).to(torch.int32)  # (N, 2) per-axis radii in gsplat 1.5
    first_hit = _first_hit(means, quats, scales, opacities, viewmat, K, camera, eps2d, near,
                           hit_threshold) if return_first_hit else None
    return image, alpha, depth, first_hit, radii


@torch.no_grad()
def _first_hit(means, quats, scales, opacities, viewmat, K, camera, eps2d, near, hit_threshold) -> Tensor:
    proj = project_gaussians(means, quats, scales, viewmat[:3, :3], viewmat[:3, 3], K, camera.width,
                             camera.height, eps2d=eps2d, near=near)
    ones = torch.ones_like(opacities)[:, None]
    _, _, first_hit = rasterize_reference(proj.means2d, proj.conics, opacities, ones, ones[0], proj.depths,
                                          proj.boxes, camera.width, camera.height, return_first_hit=True,
                                          hit_threshold=hit_threshold)
    return first_hit
