"""The built-in prior's pseudo-appearance of an avatar: its unseen Gaussians' colours carried from
the sources of Stage I's fill. Stage II's target (``Stage2Plan.propagated_colors``) and the editor's
fill for a redo without a Stage II plan (``EditSession``) are this one function.

The sources are ``AvatarState.trusted_sources``: the seen flags less the Gaussians Stage I's finish
took out of its fill's sources (``AvatarState.colour_sources``: seen by their blend weight alone,
layer Gaussians that show the body), eroded as the trusted flags are. Trusted Gaussians that are no
source keep their own colour. A state from before the flags carries colours from every trusted one.
"""

from __future__ import annotations

import numpy as np
import torch

from ..avatar.layer_cover import model_body_under_layer
from .propagation import propagate_colors
from .wrap_fill import wrap_fill_colors


def pseudo_appearance(state, trusted: torch.Tensor, colors: torch.Tensor, neighbours: np.ndarray, erosion: int,
                      *, grazing_rule: bool, propagation: str = "wrap") -> torch.Tensor:
    """(N,3) colours for ``state`` (an ``AvatarState``): ``colors`` (canonical) carried from the
    sources to the others by ``propagation`` (``wrap``: ``wrap_fill_colors``, its hair read on the
    sources eroded by at most 1 texel; ``diffusion``: ``propagate_colors``). ``trusted``: (N,) bool,
    the painted trusted flags; ``erosion``: texels the trusted flags were eroded by; ``grazing_rule``:
    whether seen Gaussians at grazing incidence are no source (``wrap_fill.grazing_rule_for``).
    Regions under a redo take the wrap fill's low-frequency fill only."""
    model = state.model
    colors = colors.detach().cpu()
    trusted = trusted.cpu()
    sources = trusted if state.colour_sources is None else state.trusted_sources(neighbours, erosion).cpu()
    if propagation == "diffusion":
        out = propagate_colors(model.base_positions.cpu(), model.parts(), sources, colors, neighbours)
    else:
        out = wrap_fill_colors(model.base_positions.cpu(), model.parts(), sources, colors, neighbours,
                               normals=model.base_normals.cpu() if grazing_rule else None,
                               no_mirror=state.edits.redone, under_layer=model_body_under_layer(model),
                               layer_grid=model.layer_grid(), hair_seen=state.trusted_sources(neighbours, min(erosion, 1)),
                               surface_normals=model.base_normals.cpu(), cut_colors=state.cut_colors,
                               row_seen=state.trusted_sources(neighbours, 0),
                               occluded_colors=state.occluded_colors, hair_colors=state.hair_colors)
    return torch.where((trusted & ~sources)[:, None], colors.clamp(0, 1).to(out.dtype), out)
