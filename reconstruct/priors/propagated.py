"""The built-in prior: no learned weights. The unseen view is pulled towards the same view of the
avatar rendered with *wrap-around appearance*: each garment's low-frequency colours and
height-periodic patterns carried round from the sides the video saw to the unseen side, front-only
details (a chest print, the face) left out (reconstruct.appearance.wrap_fill; the earlier diffusion
fill with mirrored colours, reconstruct.appearance.propagation, with ``propagation=diffusion``), a
pseudo-target supplied by the caller.

It is a pseudo-target regression, not a diffusion model: the loss is the mean squared error
between the render and the (stop-gradient) pseudo-target over the body's pixels."""

from __future__ import annotations

import torch

from .base import GuidanceInput, GuidanceOutput, GuidancePrior, PriorError


class PropagatedAppearancePrior(GuidancePrior):
    name = "wrap-around appearance (built-in pseudo-target, no weights)"

    def loss(self, inp: GuidanceInput) -> GuidanceOutput:
        if inp.pseudo_target is None:
            raise PriorError("the propagated-appearance prior needs a pseudo-target renderer from the guidance step")
        with torch.no_grad():
            target = inp.pseudo_target().detach()
        if target.shape != inp.render.shape:
            raise PriorError(f"pseudo-target shape {tuple(target.shape)} != render shape {tuple(inp.render.shape)}")
        diff = (inp.render - target) ** 2
        if inp.alpha is not None:
            w = inp.alpha.detach().clamp(0, 1)[..., None]
            loss = (diff * w).sum() / (3 * w.sum()).clamp_min(1.0)
        else:
            loss = diff.mean()
        return GuidanceOutput(loss, {"prior_mse": float(loss.detach())}, target)


def build_prior(kind: str, path: str | None = None, **kwargs) -> GuidancePrior:
    """``builtin`` or ``zero123`` (the latter from a diffusers-format folder at ``path``)."""
    if kind == "builtin":
        return PropagatedAppearancePrior()
    if kind == "zero123":
        if not path:
            raise PriorError("the zero123 prior needs --prior-path DIR (a diffusers-format Zero123 folder)")
        try:
            from .zero123 import Zero123Prior
        except ImportError as exc:
            raise PriorError(f"the zero123 prior needs the optional packages diffusers and transformers "
                             f"(pip install 'wonderhuman-studio[zero123]'): {exc}") from exc
        return Zero123Prior(path, **kwargs)
    raise PriorError(f"unknown prior {kind!r}; choose builtin or zero123")
