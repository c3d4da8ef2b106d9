"""Stage I's last act: the Gaussians no training view ever saw take the wrap-around fill's colour
of the seen surface (``reconstruct.appearance.wrap_fill``), instead of whatever the decoder
extrapolates to texels it was never trained on.

Why. Flat discs that cover the surface without gaps (the Stage I fidelity work) leave the
unseen side with no gradient at all: its colour is the decoder's answer for untrained features,
a flat grey-mauve on the garment benchmark (`docs/stage1_fidelity.md`). The earlier layout's back
was trained, by accident, through the holes in its front and so took the front's garment colours.
The fill does on purpose what those holes did by accident, with the rules of the built-in prior:
each garment's colours all round, not the front's emblem or face.

How. The colour a Gaussian renders is ``sigmoid(decoded logit + gain * residual)``. For every
never-seen Gaussian the residual is set so that it decodes to its fill colour; nothing else
changes (seen Gaussians, geometry, the decoder). The sources are the seen flags eroded by
``erosion`` texels (Stage II's trusted flags): the last seen ring round the unseen side is the
silhouette at grazing incidence, darkened by its blend with the background. Painted visibility
(edits) counts: a region painted seen is not filled, one painted unseen is.

A garment layer's Gaussians are filled like the body's: they are one more part ("garment") whose
seen ones colour the unseen ones round the tube at the same height (the fill's band), eroded and
smoothed over the layer's own grid (``AvatarModel.neighbours``).

Stage II starts from this avatar and recomputes its own pseudo-colours from the same trusted
seen Gaussians, so the fill changes where Stage II starts, not where it is pulled to."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..appearance.propagation import erode
from ..appearance.wrap_fill import wrap_fill_colors

if TYPE_CHECKING:
    from ..avatar.state import AvatarState

# target colours are kept this far inside (0, 1) so that their logits stay finite
_COLOR_MARGIN = 1e-3


@torch.no_grad()
def fill_unseen_colors(state: AvatarState, *, erosion: int = 2, keep_ring: int = 0, grazing_rule: bool = True) -> int:
    """Set the colour residual of every Gaussian the painted seen flags call unseen so that it
    decodes to the wrap-around fill's colour. Returns how many Gaussians were filled (0 when the
    avatar has no colour residual, sees nothing or sees everything). ``grazing_rule``: seen
    Gaussians seen at grazing incidence only are no colour source (``WrapFillConfig.max_seen_angle_deg``;
    for avatars trained on one fixed background, whose silhouette colours are darkened by it)."""
    model = state.model
    cfg = model.config
    if not cfg.color_residual:
        return 0
    seen = state.edits.paint(state.seen).cpu().bool()
    unseen = ~seen
    if not bool(seen.any()) or not bool(unseen.any()):
        return 0
    neighbours = model.neighbours()  # a garment layer's Gaussians over its own grid, one more part
    trusted = torch.as_tensor(erode(seen.numpy(), neighbours, erosion))
    if not bool(trusted.any()):
        trusted = seen
    colors = model.canonical(None).colors.detach().cpu()
    filled = wrap_fill_colors(model.base_positions.cpu(), model.parts(), trusted, colors, neighbours,
                              normals=model.base_normals.cpu() if grazing_rule else None, no_mirror=state.edits.redone)
    todo = torch.as_tensor(erode(unseen.numpy(), neighbours, keep_ring)) if keep_ring else unseen
    idx = torch.nonzero(todo).squeeze(1)
    decoded_logit = model.decode_raw(None, None)["color"].detach().cpu()[idx]
    target = torch.logit(filled[idx].to(decoded_logit.dtype).clamp(_COLOR_MARGIN, 1 - _COLOR_MARGIN))
    residual = model.decoder.color_residual
    residual.data[idx.to(residual.device)] = ((target - decoded_logit) / cfg.color_residual_gain).to(
        residual.device, residual.dtype)
    return int(len(idx))
