"""The compiled CPU rasterizer: build-on-first-use of ``csrc/rasterizer.cpp`` and its autograd glue.

The extension is compiled once per (sources, torch, Python, compiler flags, CPU) into
``$WONDERHUMAN_CACHE_DIR/raster/<hash>`` (default ``~/.cache/wonderhuman``); later processes import
the cached library directly. A file lock in that folder keeps two processes from building at once.
"""

from __future__ import annotations

import fcntl
import hashlib
import importlib.util
import os
import platform
import sys
import sysconfig
import threading
from contextlib import contextmanager
from pathlib import Path

import torch
from torch import Tensor

_SOURCES = [Path(__file__).parent / "csrc" / "rasterizer.cpp"]
_CFLAGS = ["-O3", "-fopenmp", "-march=native", "-ffp-contract=off", "-fno-trapping-math"]
_LDFLAGS = ["-fopenmp"]
_MODULE = "wonderhuman_raster_cpu"

_extension = None
_build_error: Exception | None = None
_load_lock = threading.Lock()


def cache_root() -> Path:
    """The program's cache folder (``$WONDERHUMAN_CACHE_DIR`` or ``~/.cache/wonderhuman``)."""
    env = os.environ.get("WONDERHUMAN_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "wonderhuman"


def _cpu_signature() -> str:
    """CPU model and feature flags: ``-march=native`` code is only valid on the same kind of CPU."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor()
    keys = ("model name", "flags")
    return "|".join(sorted({line for line in lines if line.split(":")[0].strip() in keys}))


def build_key() -> str:
    """Hash of everything the compiled library depends on."""
    h = hashlib.sha256()
    for src in _SOURCES:
        h.update(src.read_bytes())
    for part in (torch.__version__, sys.version, sysconfig.get_config_var("EXT_SUFFIX") or "",
                 " ".join(_CFLAGS + _LDFLAGS), platform.machine(), _cpu_signature()):
        h.update(part.encode())
    return h.hexdigest()[:16]


@contextmanager
def _file_lock(path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _import_library(path: Path):
    spec = importlib.util.spec_from_file_location(_MODULE, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _build(build_dir: Path):
    from torch.utils.cpp_extension import load

    print("building the CPU rasterizer (one time, ~1-2 min)…", file=sys.stderr, flush=True)
    return load(name=_MODULE, sources=[str(s) for s in _SOURCES], extra_cflags=_CFLAGS,
                extra_ldflags=_LDFLAGS, build_directory=str(build_dir), verbose=False)


def load_extension():
    """The compiled module, building it on first use. Raises RuntimeError if it cannot be built."""
    global _extension, _build_error
    with _load_lock:
        if _extension is not None:
            return _extension
        if _build_error is not None:
            raise RuntimeError(f"the CPU rasterizer could not be built: {_build_error}") from _build_error
        build_dir = cache_root() / "raster" / build_key()
        library = build_dir / f"{_MODULE}.so"
        try:
            with _file_lock(build_dir / "build.lock"):
                if library.exists():
                    _extension = _import_library(library)
                else:
                    _extension = _build(build_dir)
        except Exception as exc:  # compiler missing, compile error, unwritable cache, ...
            _build_error = exc
            raise RuntimeError(f"the CPU rasterizer could not be built: {exc}") from exc
        return _extension


def is_available() -> bool:
    """Whether the compiled kernel can be used (builds it if needed)."""
    try:
        load_extension()
    except RuntimeError:
        return False
    return True


class _RasterizeCPU(torch.autograd.Function):
    """Autograd wrapper of the compiled forward and hand-written backward."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, background, depths, boxes, width, height,
                want_hit, hit_threshold):
        ext = load_extension()
        bins = ext.bin_gaussians(boxes, depths, width, height)
        tile_offsets, tile_gaussians, tile_slots, gaussian_offsets = bins
        image, alpha, transmittance, last, first_hit = ext.forward(
            means2d, conics, opacities, features, background, boxes, tile_offsets, tile_gaussians,
            width, height, want_hit, hit_threshold)
        ctx.save_for_backward(means2d, conics, opacities, features, background, boxes, *bins, transmittance, last)
        ctx.size = (width, height)
        ctx.mark_non_differentiable(first_hit)
        return image, alpha, first_hit

    @staticmethod
    def backward(ctx, grad_image, grad_alpha, _grad_hit):
        (means2d, conics, opacities, features, background, boxes, tile_offsets, tile_gaussians, tile_slots,
         gaussian_offsets, transmittance, last) = ctx.saved_tensors
        grads = load_extension().backward(
            means2d, conics, opacities, features, background, boxes, tile_offsets, tile_gaussians, tile_slots,
            gaussian_offsets, transmittance, last, grad_image.contiguous(), grad_alpha.contiguous(), *ctx.size)
        grad_background = (grad_image * transmittance[..., None]).sum(dim=(0, 1))
        return (*grads, grad_background, None, None, None, None, None, None)


def rasterize_cpu(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, background: Tensor,
                  depths: Tensor, boxes: Tensor, width: int, height: int, *, return_first_hit: bool = False,
                  hit_threshold: float = 0.5) -> tuple[Tensor, Tensor, Tensor | None]:
    """Composite projected Gaussians with the compiled kernel.

    Returns image (H,W,C), alpha (H,W) and first_hit (H,W) int64 or None. Differentiable w.r.t.
    means2d, conics, opacities, features and background."""
    tensors = [t.contiguous() for t in (means2d, conics, opacities, features, background, depths)]
    image, alpha, first_hit = _RasterizeCPU.apply(*tensors, boxes.contiguous(), int(width), int(height),
                                                  bool(return_first_hit), float(hit_threshold))
    return image, alpha, (first_hit if return_first_hit else None)
