"""Guidance priors for unseen views (paper Sec. 3.2): one interface, several implementations."""

from .base import CameraDelta, GuidanceInput, GuidanceOutput, GuidancePrior, PriorError

__all__ = ["CameraDelta", "GuidanceInput", "GuidanceOutput", "GuidancePrior", "PriorError"]
