"""Input checks of ``rasterization``: shapes, dtypes, devices, finiteness and positive scales.

Every failure is a ValueError that names the tensor and says what was expected and what was found,
so that bad data never turns into a silent NaN image."""

from __future__ import annotations

import torch
from torch import Tensor


def _first_index(mask: Tensor) -> tuple[int, ...]:
    return tuple(int(i) for i in torch.nonzero(mask)[0])


def check_shapes(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, features: Tensor,
                 background: Tensor | None) -> None:
    """(N,3), (N,4), (N,3), (N,), (N,C) with C >= 1, and (C,) for the background."""
    if not isinstance(means, Tensor) or means.dim() != 2 or means.shape[1] != 3:
        found = tuple(means.shape) if isinstance(means, Tensor) else type(means).__name__
        raise ValueError(f"rasterization: means: expected shape (N, 3), found {found}")
    n = means.shape[0]
    expected = {"quats": (quats, (n, 4)), "scales": (scales, (n, 3)), "opacities": (opacities, (n,))}
    for name, (tensor, shape) in expected.items():
        if not isinstance(tensor, Tensor) or tuple(tensor.shape) != shape:
            found = tuple(tensor.shape) if isinstance(tensor, Tensor) else type(tensor).__name__
            raise ValueError(f"rasterization: {name}: expected shape {shape}, found {found}")
    if not isinstance(features, Tensor) or features.dim() != 2 or features.shape[0] != n or features.shape[1] < 1:
        found = tuple(features.shape) if isinstance(features, Tensor) else type(features).__name__
        raise ValueError(f"rasterization: features: expected shape ({n}, C) with C >= 1, found {found}")
    if background is not None and (not isinstance(background, Tensor)
                                   or tuple(background.shape) != (features.shape[1],)):
        found = tuple(background.shape) if isinstance(background, Tensor) else type(background).__name__
        raise ValueError(f"rasterization: background: expected shape ({features.shape[1]},), found {found}")


def check_types(named: dict[str, Tensor]) -> None:
    """One dtype (float32 or float64) and one device for all tensors."""
    first_name, first = next(iter(named.items()))
    if first.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"rasterization: {first_name}: expected dtype torch.float32 or torch.float64, "
                         f"found {first.dtype}")
    for name, tensor in named.items():
        if tensor.dtype != first.dtype:
            raise ValueError(f"rasterization: {name}: expected dtype {first.dtype} (as {first_name}), "
                             f"found {tensor.dtype}")
        if tensor.device != first.device:
            raise ValueError(f"rasterization: {name}: expected device {first.device} (as {first_name}), "
                             f"found {tensor.device}")


def check_values(named: dict[str, Tensor]) -> None:
    """All values finite; scales strictly positive. (A finite sum proves a tensor finite, which
    keeps the common case to one reduction per tensor.)"""
    for name, tensor in named.items():
        if tensor.numel() == 0 or torch.isfinite(tensor.detach().sum()):
            continue
        bad = ~torch.isfinite(tensor.detach())
        if bad.any():
            raise ValueError(f"rasterization: {name} has {int(bad.sum())} non-finite value(s), "
                             f"first at index {_first_index(bad)}")
    scales = named["scales"].detach()
    if scales.numel() == 0 or scales.min() > 0:
        return
    bad = scales <= 0
    if bad.any():
        raise ValueError(f"rasterization: scales must be > 0 (standard deviations); {int(bad.sum())} "
                         f"value(s) are <= 0, first at index {_first_index(bad)}")


def check_inputs(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, features: Tensor,
                 background: Tensor | None) -> None:
    """All the checks, in the order shapes, types, values."""
    check_shapes(means, quats, scales, opacities, features, background)
    named = {"means": means, "quats": quats, "scales": scales, "opacities": opacities, "features": features}
    if background is not None:
        named["background"] = background
    check_types(named)
    check_values(named)
