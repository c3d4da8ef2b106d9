"""Differentiable 3D Gaussian rasterization (see ``rasterize.rasterization``).

Backends: gsplat's CUDA kernels where CUDA is present, a compiled C++ CPU kernel with a
hand-written backward (built on first use), and a pure-torch reference."""

from .rasterize import RasterOutput, available_backends, rasterization

__all__ = ["RasterOutput", "available_backends", "rasterization"]
