"""The one entry point of the rasterizer: ``rasterization(...) -> RasterOutput``."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from torch import Tensor

from ..camera import Camera
from . import cpu_backend, gsplat_backend
from .projection import project_gaussians
from .reference import rasterize_reference
from .validate import check_inputs

BACKENDS = ("auto", "cpu", "torch", "gsplat")
_warned_fallback = False


@dataclass
class RasterOutput:
    """What ``rasterization`` returns.

    image (H,W,C) composited features over the background; alpha (H,W) accumulated opacity
    sum_i w_i with w_i = alpha_i T_i; depth (H,W) expected camera depth sum_i w_i z_i / max(alpha,
    1e-10), 0 where alpha == 0; first_hit (H,W) int64 index of the Gaussian, among those composited
    at the pixel (before its early termination), after which the pixel's accumulated opacity
    1 - T first reaches ``hit_threshold`` -- the surface the ray hits (paper Eq. 7; with a
    per-Gaussian alpha test instead, rays through the gaps between splats of the front surface
    would mark Gaussians of the back as seen) --, -1 where none, or None when not asked for; radii (N,) int32 pixel
    radius, 0 = culled (the gsplat backend reports its own, per-axis 3.33-sigma radius).
    """

    image: Tensor
    alpha: Tensor
    depth: Tensor
    first_hit: Tensor | None
    radii: Tensor


def available_backends() -> list[str]:
    """Usable backends, most preferred first ("torch" always works)."""
    found = ["gsplat"] if gsplat_backend.is_available() else []
    if cpu_backend.is_available():
        found.append("cpu")
    return found + ["torch"]


def _resolve_backend(backend: str, means: Tensor) -> str:
    global _warned_fallback
    if backend not in BACKENDS:
        raise ValueError(f"rasterization: backend must be one of {BACKENDS}, found {backend!r}")
    if backend == "gsplat":
        if not gsplat_backend.is_available():
            raise RuntimeError("rasterization: the gsplat backend needs CUDA and gsplat's CUDA extension")
        if not means.is_cuda or means.dtype != torch.float32:
            raise ValueError(f"rasterization: the gsplat backend needs float32 CUDA tensors, "
                             f"found {means.dtype} on {means.device}")
        return backend
    if backend == "cpu":
        if means.device.type != "cpu":
            raise ValueError(f"rasterization: the cpu backend needs CPU tensors, found {means.device}")
        cpu_backend.load_extension()  # raises RuntimeError with the build error
        return backend
    if backend == "torch":
        return backend
    if means.is_cuda and means.dtype == torch.float32 and gsplat_backend.is_available():
        return "gsplat"
    if means.device.type == "cpu" and cpu_backend.is_available():
        return "cpu"
    if not _warned_fallback:
        _warned_fallback = True
        warnings.warn("rasterization: no compiled rasterizer for these tensors; using the (slow) pure-torch "
                      "one", RuntimeWarning, stacklevel=3)
    return "torch"


def _camera_tensors(camera: Camera, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    as_tensor = lambda a: torch.as_tensor(a, dtype=like.dtype, device=like.device)  # noqa: E731
    return as_tensor(camera.R), as_tensor(camera.t), as_tensor(camera.K)


def _empty_output(background: Tensor, camera: Camera, return_first_hit: bool) -> RasterOutput:
    H, W = camera.height, camera.width
    zeros = torch.zeros(H, W, dtype=background.dtype, device=background.device)
    image = background * torch.ones(H, W, 1, dtype=background.dtype, device=background.device)
    first_hit = torch.full((H, W), -1, dtype=torch.long, device=background.device) if return_first_hit else None
    return RasterOutput(image, zeros, zeros.clone(), first_hit,
                        torch.zeros(0, dtype=torch.int32, device=background.device))


def rasterization(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    features: Tensor,
    camera: Camera,
    *,
    background: Tensor | None = None,
    backend: str = "auto",
    return_first_hit: bool = False,
    hit_threshold: float = 0.5,
    eps2d: float = 0.3,
    near: float | None = None,
) -> RasterOutput:
    """Render N 3D Gaussians seen by ``camera``.

    means (N,3) world positions; quats (N,4) rotations (w, x, y, z), normalised here; scales (N,3)
    positive standard deviations; opacities (N,); features (N,C) any C >= 1 channels to composite;
    background (C,) or None (zeros). Differentiable w.r.t. all of them.

    backend: "auto" (gsplat on CUDA when it loads, else the compiled CPU kernel, else pure torch
    with a one-time warning), "cpu", "torch" or "gsplat". ``near`` defaults to ``camera.near``.
    Raises ValueError on wrong shapes, mixed dtypes/devices, non-finite values, scales <= 0,
    eps2d < 0 or near <= 0.
    """
    check_inputs(means, quats, scales, opacities, features, background)
    if background is None:
        background = torch.zeros(features.shape[1], dtype=features.dtype, device=features.device)
    if eps2d < 0:
        raise ValueError(f"rasterization: eps2d must be >= 0, found {eps2d}")
    near = camera.near if near is None else float(near)
    if not near > 0:
        raise ValueError(f"rasterization: near must be > 0, found {near}")
    backend = _resolve_backend(backend, means)
    if means.shape[0] == 0:
        return _empty_output(background, camera, return_first_hit)
    if backend == "gsplat":
        image, alpha, depth, first_hit, radii = gsplat_backend.rasterize_gsplat(
            means, quats, scales, opacities, features, background, camera, eps2d=eps2d, near=near,
            return_first_hit=return_first_hit, hit_threshold=hit_threshold)
        return RasterOutput(image, alpha, depth, first_hit, radii)

    R, t, K = _camera_tensors(camera, means)
    proj = project_gaussians(means, quats, scales, R, t, K, camera.width, camera.height, eps2d=eps2d, near=near)
    # the depth is composited as one more feature channel over a zero background
    channels = torch.cat([features, proj.depths[:, None]], dim=1)
    back = torch.cat([background, background.new_zeros(1)])
    composite = cpu_backend.rasterize_cpu if backend == "cpu" else rasterize_reference
    image, alpha, first_hit = composite(proj.means2d, proj.conics, opacities, channels, back, proj.depths,
                                        proj.boxes, camera.width, camera.height,
                                        return_first_hit=return_first_hit, hit_threshold=hit_threshold)
    image, depth_sum = image.split([features.shape[1], 1], dim=-1)
    depth = depth_sum[..., 0] / alpha.clamp_min(1e-10)
    return RasterOutput(image, alpha, depth, first_hit, proj.radii)
