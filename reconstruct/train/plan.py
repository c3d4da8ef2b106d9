"""A stage is a plan: what it optimises and at which learning rates, the mix of step kinds, and
its length and learning-rate decay (``StageSettings``). The trainer runs whatever plan it is given
on the same avatar state; Stage II is a second plan (``reconstruct.stage2.plan``), not a second
kind of trainer."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .config import Stage1Config, StageSettings
from .steps import GivenViewStep, TrainingStep
from .unseen_fill import fill_unseen_colors

if TYPE_CHECKING:
    from ..avatar.state import AvatarState


class StagePlan:
    """The interface every stage implements (Stage I's is the whole of ``Stage1Plan``)."""

    stage: int
    settings: StageSettings
    steps: dict[str, TrainingStep]

    def param_groups(self, state: AvatarState) -> list[dict]:
        """Adam parameter groups (``params``, ``lr``, ``name``)."""
        raise NotImplementedError

    def next_kind(self, rng: np.random.Generator) -> str:
        """The kind of the next step (a key of ``steps``)."""
        return "given"

    def status(self, stage_step: int) -> dict:
        """Numbers of the plan at a step of the stage, for the log, the progress bar and the
        studio (e.g. λ_SDS)."""
        return {}

    def finish(self, state: AvatarState) -> str | None:
        """Called once when the stage has used up its steps or minutes (before the final
        evaluation and checkpoint). Returns a line for the log, or None."""
        return None

    def state_dict(self) -> dict:
        """What a checkpoint must hold to continue the plan: plain data and tensors only."""
        return {"settings": self.settings.to_dict()}

    def describe(self) -> str:
        s = self.settings
        return f"{s.iters} steps" + (f" or {s.minutes:g} min" if s.minutes else "")


class Stage1Plan(StagePlan):
    """Stage I (paper Sec. 3.1, Eq. 11): given-view steps on the video, decoder and feature map
    optimised, first hits marked seen."""

    stage = 1

    def __init__(self, config: Stage1Config) -> None:
        self.settings = config
        self.steps = {"given": GivenViewStep(config, marks_seen=True)}

    def param_groups(self, state: AvatarState) -> list[dict]:
        c = self.settings
        return [{"params": state.model.decoder.parameters(), "lr": c.lr_decoder, "name": "decoder"},
                {"params": [state.model.features], "lr": c.lr_features, "name": "features"},
                *state.model.layer_param_groups(c.lr_features, c.lr_decoder)]  # [] without a garment layer

    def finish(self, state: AvatarState) -> str | None:
        """The never-seen Gaussians take the wrap-around fill's colours (``fill_unseen``)."""
        if not self.settings.fill_unseen:
            return None
        n = fill_unseen_colors(state, keep_ring=self.settings.fill_unseen_ring)
        return f"Stage I: {n} Gaussians no training view saw were painted with the seen side's colours" if n else None
