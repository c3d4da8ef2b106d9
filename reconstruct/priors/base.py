"""The guidance-prior interface shared by Stage II's dual-space optimisation.

A prior receives the avatar rendered from an unseen view (with gradient), the conditioning
reference image (the Stage I canonical render in canonical space, the selected input frame in
observation space), the camera change from the reference view to the rendered one, and the
run's progress; it returns a scalar loss whose gradient flows into the render only.

Images are (H, W, 3) float tensors in [0, 1], already cropped to the body and resized to the
prior's input size by the caller (paper A.2: mask crops resized to 256 x 256).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Callable

import torch


class PriorError(ValueError):
    """A prior that cannot be built from what the user supplied (missing or wrong weights)."""


@dataclass(frozen=True)
class CameraDelta:
    """Zero123's relative camera: target minus reference, polar angle measured from +up (radians),
    azimuth (radians, positive = camera moves towards the avatar's left), radius (scene units).
    ``reference_polar`` is the reference view's absolute polar angle (Stable Zero123's 4th entry)."""

    polar: float
    azimuth: float
    radius: float = 0.0
    reference_polar: float = math.pi / 2

    def zero123_vector(self) -> list[float]:
        """[Δpolar, sin Δazimuth, cos Δazimuth, Δradius] (Zero123's conditioning)."""
        return [self.polar, math.sin(self.azimuth), math.cos(self.azimuth), self.radius]

    def stable_zero123_vector(self) -> list[float]:
        """Stable Zero123: the 4th entry is the reference view's absolute polar angle."""
        return [self.polar, math.sin(self.azimuth), math.cos(self.azimuth), self.reference_polar]


@dataclass
class GuidanceInput:
    render: torch.Tensor  # (H,W,3) the avatar from the unseen view, requires grad
    reference: torch.Tensor  # (H,W,3) the conditioning image
    delta: CameraDelta
    progress: float = 0.0  # fraction of Stage II done, in [0, 1] (for annealed noise levels)
    alpha: torch.Tensor | None = None  # (H,W) the render's coverage
    space: str = "observation"  # "canonical" or "observation"
    # the same view rendered with the prior's own appearance (used by priors that build a
    # pseudo-target from the avatar itself, e.g. the built-in propagated-appearance prior)
    pseudo_target: Callable[[], torch.Tensor] | None = None


@dataclass
class GuidanceOutput:
    loss: torch.Tensor  # scalar, gradient reaches ``render`` only
    info: dict = field(default_factory=dict)  # numbers for the metrics log (e.g. the timestep)
    target: torch.Tensor | None = None  # (H,W,3) what the render is pulled towards, for display


class GuidancePrior(ABC):
    """A prior for unseen views. ``name`` is shown in the UI and written into run records."""

    name: str = "prior"

    @abstractmethod
    def loss(self, inp: GuidanceInput) -> GuidanceOutput:
        ...

    def describe(self) -> str:
        return self.name
