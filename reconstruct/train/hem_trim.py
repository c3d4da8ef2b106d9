"""Trimming a garment layer's hem part way through Stage I.

The garment layer is built longer than most garments (``avatar/garment_layer.py``): below a photo's
hem it hangs in front of the legs, and training makes it opaque there in the legs' colours, since
the image fits either way. In the training view nothing shows; once the legs move (``export
--novel walk``) those Gaussians hang from the hem as a band of the legs' colour. Made transparent
only at the end of the stage, the body behind them shows what it learnt under them: the hem's
pixels, white knees on the grey skirt ("Hands by the cloth that drew it", tried). Trimmed part way
through, the rest of the stage trains the legs behind them on the legs' pixels.

Which Gaussians: those the layer's hem rule (``avatar.layer_through.layer_shows_body``) finds, the
seen opaque ones from each column's bottom up whose colour is the body's just under the hem.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..avatar.layer_through import model_layer_shows_body

if TYPE_CHECKING:
    from ..avatar.state import AvatarState


@torch.no_grad()
def trim_layer_hem(state: AvatarState, max_passes: int = 4) -> int:
    """Trim the seen garment-layer Gaussians under the hem that show the body
    (``AvatarModel.trim_layer``: opacity 0 for good) and unmark them seen (they are no colour source
    for the layer's unseen side; at opacity 0 no first hit marks them again). The rule is read
    again on what is left, up to ``max_passes`` times while it finds more: a trimmed Gaussian no
    longer hides the body behind it, which adds to the legs' reference colours, and the column's
    walk up from the hem goes past it (grey skirt photo, end of Stage I: 65 found, then 8 more).
    Returns how many were trimmed (0 without a layer)."""
    model = state.model
    if model.layer is None or model.num_layer == 0:
        return 0
    colors = model.canonical(None).colors.detach().cpu()  # trimming changes opacities, not colours
    total = 0
    for _ in range(max_passes):
        seen = state.edits.paint(state.seen).cpu().bool()
        on_layer = torch.as_tensor(model_layer_shows_body(model, seen, colors)[model.num_body:])
        n = model.trim_layer(on_layer)
        state.seen[model.num_body:] &= ~on_layer.to(state.seen.device)
        total += n
        if not n:
            break
    return total
