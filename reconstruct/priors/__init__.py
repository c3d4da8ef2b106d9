"""Guidance priors for unseen views (paper Sec. 3.2): one interface, several implementations."""

from .base import CameraDelta, GuidanceInput, GuidanceOutput, GuidancePrior, PriorError

from .propagated import PropagatedAppearancePrior, build_prior

__all__ = ["CameraDelta", "GuidanceInput", "GuidanceOutput", "GuidancePrior", "PriorError",
           "PropagatedAppearancePrior", "build_prior"]
# Zero123Prior (reconstruct.priors.zero123) needs the optional diffusers/transformers: import it from there.
