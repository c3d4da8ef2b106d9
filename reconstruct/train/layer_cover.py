"""Cloth is opaque where the silhouette says there is something: the garment layer's cover prior.

A layer Gaussian's opacity is learned so that the layer can fade where the silhouette shows nothing
(the alpha loss). Where the layer stands in front of a leg, though, the rendered alpha is 1 whatever
its opacity (the leg behind is opaque), so nothing holds it opaque there: the body under the cloth
learns the cloth's colour, and the layer's rows went half transparent, in stripes (trained wide
trousers: median layer opacity 0.42, every other row near 0). Seen edge on, at the silhouette of a
leg or from the side, such a layer lets the background through (holes at the trousers' edges).

``layer_cover_term``: the mean (1 - opacity) over the layer Gaussians of one training view whose
posed centre projects onto the frame's inner mask: the pixels at least ``Stage1Config.layer_cover_inset``
pixels inside it (``FrameTarget.inner_mask``, eroded once per frame; pixel (row i, column j) spans
[j, j+1) x [i, i+1)). Gaussians outside the mask or at its edge are
left to the alpha loss, which fades the layer where it stands beyond the person. The prior over the
whole layer (``lambda_layer_opaque``) also held those opaque and cost 1.3-1.5 dB (docs/loose_clothing.md).
"""

from __future__ import annotations

import torch


def inside_mask(means: torch.Tensor, camera, inner: torch.Tensor) -> torch.Tensor:
    """(K,) bool: which of the (K,3) world points project, in front of ``camera``, onto a True
    pixel of the (H,W) bool ``inner`` (a mask eroded by ``evaluate.inner_mask``)."""
    if len(means) == 0:
        return torch.zeros(0, dtype=torch.bool, device=means.device)
    R = torch.as_tensor(camera.R, dtype=means.dtype, device=means.device)
    t = torch.as_tensor(camera.t, dtype=means.dtype, device=means.device)
    pc = means.detach() @ R.T + t
    z = pc[:, 2]
    front = z > 1e-6
    zs = torch.where(front, z, torch.ones_like(z))
    col = torch.floor(camera.fx * pc[:, 0] / zs + camera.cx)
    row = torch.floor(camera.fy * pc[:, 1] / zs + camera.cy)
    H, W = inner.shape
    ok = front & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    out = torch.zeros_like(ok)
    out[ok] = inner[row[ok].long(), col[ok].long()]
    return out


def layer_cover_term(opacities: torch.Tensor, means: torch.Tensor, ids: torch.Tensor, num_body: int,
                     camera, inner: torch.Tensor) -> torch.Tensor | None:
    """Mean (1 - opacity) over the garment-layer Gaussians among the decoded ones that project onto
    ``inner`` (see the module); None when none does. ``opacities``: (N+M,) of the whole avatar;
    ``means``: (K,3) posed centres of the decoded Gaussians; ``ids``: (K,) their ids in N + M."""
    layer = ids >= num_body
    if not bool(layer.any()):
        return None
    ids, means = ids[layer], means[layer]
    inside = inside_mask(means, camera, inner)
    if not bool(inside.any()):
        return None
    return (1.0 - opacities[ids[inside]]).mean()


def view_cover_term(model, means: torch.Tensor, index: torch.Tensor | None, camera,
                    inner: torch.Tensor) -> torch.Tensor | None:
    """``layer_cover_term`` for one training view of ``model`` (an AvatarModel): ``means`` the posed
    centres of the Gaussians decoded in it, ``index`` their ids (None: all of them)."""
    ids = torch.arange(model.num_gaussians, device=means.device) if index is None else index
    return layer_cover_term(model.opacities(), means, ids, model.num_body, camera, inner)
