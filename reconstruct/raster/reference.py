"""Pure-torch Gaussian compositing: the reference of the tests (in float64) and the fallback backend.

It implements exactly the rules of the compiled kernel (``csrc/rasterizer.cpp``), with autograd
for the gradients and no tiles:

1. list every (Gaussian, pixel) pair of the Gaussians' pixel boxes;
2. order the pairs by pixel, then by camera depth (ties: Gaussian index);
3. walk the per-pixel lists in chunks of ``layers`` entries: alpha = min(0.99, o exp(-sigma)),
   pairs with alpha < 1/255 are skipped, a pixel stops before the first Gaussian that would take
   its transmittance below 1e-4; a pixel that stopped stays stopped in every later chunk.

Works on any device and float dtype; memory grows with the number of pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

MIN_ALPHA = 1.0 / 255.0
MAX_ALPHA = 0.99
MIN_TRANSMITTANCE = 1e-4


@dataclass
class _Pairs:
    """(Gaussian, pixel) pairs sorted by pixel then depth; ``slot`` is the position in the pixel's list."""

    gaussian: Tensor
    pixel: Tensor
    slot: Tensor
    counts: Tensor  # (P,) list length per pixel


def _box_pairs(boxes: Tensor, depths: Tensor, width: int, height: int) -> _Pairs:
    device = boxes.device
    boxes = boxes.long()
    bw = (boxes[:, 1] - boxes[:, 0] + 1).clamp_min(0)
    bh = (boxes[:, 3] - boxes[:, 2] + 1).clamp_min(0)
    area = bw * bh
    gaussian = torch.repeat_interleave(torch.arange(len(boxes), device=device), area)
    first = torch.repeat_interleave(torch.cumsum(area, 0) - area, area)
    local = torch.arange(len(gaussian), device=device) - first
    x = boxes[gaussian, 0] + local % bw[gaussian]
    y = boxes[gaussian, 2] + local // bw[gaussian]
    pixel = y * width + x

    rank = torch.empty(len(depths), dtype=torch.long, device=device)
    rank[torch.sort(depths.detach(), stable=True).indices] = torch.arange(len(depths), device=device)
    order = torch.argsort(pixel * len(depths) + rank[gaussian])
    gaussian, pixel = gaussian[order], pixel[order]
    counts = torch.bincount(pixel, minlength=width * height)
    slot = torch.arange(len(pixel), device=device) - (torch.cumsum(counts, 0) - counts)[pixel]
    return _Pairs(gaussian, pixel, slot, counts)


def _pair_alpha(pairs: _Pairs, means2d: Tensor, conics: Tensor, opacities: Tensor, width: int) -> Tensor:
    """alpha of every pair, 0 where it is below 1/255 (the pair is skipped)."""
    g = pairs.gaussian
    dx = (pairs.pixel % width).to(means2d.dtype) + 0.5 - means2d[g, 0]
    dy = (pairs.pixel // width).to(means2d.dtype) + 0.5 - means2d[g, 1]
    a, b, c = conics[g].unbind(-1)
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = torch.clamp(opacities[g] * torch.exp(-sigma), max=MAX_ALPHA)
    return torch.where(alpha >= MIN_ALPHA, alpha, torch.zeros_like(alpha))


def rasterize_reference(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    background: Tensor,
    depths: Tensor,
    boxes: Tensor,
    width: int,
    height: int,
    *,
    return_first_hit: bool = False,
    hit_threshold: float = 0.5,
    layers: int = 32,
) -> tuple[Tensor, Tensor, Tensor | None]:
    """Composite projected Gaussians (see the module docstring for the rules).

    Returns image (H,W,C), alpha (H,W) and first_hit (H,W) int64 or None; differentiable w.r.t.
    means2d, conics, opacities, features and background by autograd."""
    P, C = width * height, features.shape[1]
    pairs = _box_pairs(boxes, depths, width, height)
    alpha = _pair_alpha(pairs, means2d, conics, opacities, width)
    transmittance = torch.ones(P, dtype=features.dtype, device=features.device)
    color = torch.zeros(P, C, dtype=features.dtype, device=features.device)
    weight = torch.zeros(P, dtype=features.dtype, device=features.device)
    done = torch.zeros(P, dtype=torch.bool, device=features.device)
    included = torch.zeros(len(alpha), dtype=torch.bool, device=features.device)
    opacity_after = torch.zeros(len(alpha), dtype=alpha.dtype, device=alpha.device)  # 1 - T after each pair

    depth_max = int(pairs.counts.max()) if len(alpha) else 0
    for start in range(0, depth_max, layers):
        sel = torch.nonzero((pairs.slot >= start) & (pairs.slot < start + layers)).squeeze(1)
        active = torch.nonzero(pairs.counts > start).squeeze(1)
        row = torch.empty(P, dtype=torch.long, device=features.device)
        row[active] = torch.arange(len(active), device=features.device)
        index = (row[pairs.pixel[sel]], pairs.slot[sel] - start)

        a = torch.zeros(len(active), layers, dtype=alpha.dtype, device=alpha.device).index_put(index, alpha[sel])
        t0 = transmittance[active]
        keep = 1.0 - a
        after = t0[:, None] * torch.cumprod(keep, dim=1)
        before = torch.cat([t0[:, None], after[:, :-1]], dim=1)
        live = (~done[active])[:, None] & (a > 0)
        take = live & (after >= MIN_TRANSMITTANCE)
        w = torch.where(take, a * before, torch.zeros_like(a))

        w_pair = w[index]
        color = color.index_add(0, pairs.pixel[sel], w_pair[:, None] * features[pairs.gaussian[sel]])
        weight = weight.index_add(0, active, w.sum(dim=1))
        t_new = t0 * torch.where(take, keep, torch.ones_like(keep)).prod(dim=1)
        transmittance = transmittance.index_copy(0, active, t_new)
        done[active] |= (live & (after < MIN_TRANSMITTANCE)).any(dim=1)
        included[sel] = take[index]
        opacity_after[sel] = (1.0 - after)[index].detach()

    if depth_max == 0:
        # nothing to composite (every Gaussian culled): keep the outputs attached to the inputs, with
        # zero gradients, as the compiled kernel's are -- else a loss on them cannot be backpropagated
        zero = sum((t * 0.0).sum() for t in (means2d, conics, opacities, features))
        color, weight = color + zero, weight + zero
    image = (color + transmittance[:, None] * background).reshape(height, width, C)
    first_hit = None
    if return_first_hit:
        first_hit = _first_hit(pairs, opacity_after, included, hit_threshold, P).reshape(height, width)
    return image, weight.reshape(height, width), first_hit


def _first_hit(pairs: _Pairs, opacity_after: Tensor, included: Tensor, threshold: float, P: int) -> Tensor:
    """Per pixel, the first included Gaussian in depth order after which the pixel's accumulated
    opacity 1 - T is at least ``threshold`` (the surface the ray hits), else -1."""
    hits = torch.nonzero(included & (opacity_after >= threshold)).squeeze(1)
    first = torch.full((P,), len(opacity_after), dtype=torch.long, device=opacity_after.device)
    first.scatter_reduce_(0, pairs.pixel[hits], hits, reduce="amin")
    found = first < len(opacity_after)
    ids = torch.full((P,), -1, dtype=torch.long, device=opacity_after.device)
    ids[found] = pairs.gaussian[first[found]]
    return ids
