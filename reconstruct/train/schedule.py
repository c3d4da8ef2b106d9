"""Scheduled values (threestudio's ``[start_step, start_value, end_value, end_step]``), step learning
rates, and the paper's halving schedule of the SDS weight (Eq. 14)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Ramp:
    """Linear from ``start_value`` at ``start_step`` to ``end_value`` at ``end_step``, constant outside."""

    start_step: float
    start_value: float
    end_value: float
    end_step: float

    @classmethod
    def parse(cls, value) -> "Ramp":
        if isinstance(value, Ramp):
            return value
        if isinstance(value, (int, float)):
            return cls(0, float(value), float(value), 1)
        if isinstance(value, str):
            value = [float(v) for v in value.strip("[]()").split(",")]
        if len(value) != 4:
            raise ValueError(f"a scheduled value is a number or [start_step, start_value, end_value, end_step], found {value!r}")
        return cls(*(float(v) for v in value))

    def __call__(self, step: float) -> float:
        if self.end_step <= self.start_step or step <= self.start_step:
            return self.start_value if step < self.end_step else self.end_value
        t = min(1.0, (step - self.start_step) / (self.end_step - self.start_step))
        return self.start_value + t * (self.end_value - self.start_value)


def step_decay(progress: float, milestones: tuple[float, ...], gamma: float) -> float:
    """Multiplier gamma^k where k milestones (fractions of the run) have been passed."""
    return gamma ** sum(progress >= m for m in milestones)


def halving(value0: float, epoch: float, t0: float, k: float) -> float:
    """Paper Eq. 14: value0 / 2^floor((epoch - t0) / k) once epoch >= t0, value0 before."""
    if k <= 0:
        raise ValueError(f"halving interval k must be positive, found {k}")
    if epoch < t0:
        return value0
    return value0 / 2.0 ** math.floor((epoch - t0) / k)
