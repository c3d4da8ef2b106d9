"""Scheduled values: one type for every number that changes over a training stage.

threestudio writes a scheduled value as ``[start_step, start_value, end_value, end_step]``: the
start value until ``start_step``, the end value from ``end_step``, linear in between. The paper
and GaussianAvatar also use piecewise-constant schedules: the learning rate is multiplied by γ
at fixed fractions of the run, and λ_SDS is halved every k epochs from t0 (Eq. 14). ``Scheduled``
holds all three shapes behind one call, ``value(x)``, where ``x`` is whatever clock the user
chose (a stage's fraction done, its steps, or schedule epochs):

* ``Scheduled.ramp(start_step, start_value, end_value, end_step)`` -- threestudio's linear ramp
  (used for Zero123's annealed maximum noise level);
* ``Scheduled.drops(value, at=(x1, x2, ...), factor=γ)`` -- ``value · γ^k`` after the k-th of the
  points ``at`` (the learning-rate decay);
* ``Scheduled.halving(value, t0, k)`` -- ``value / 2^floor((x - t0) / k)`` from ``t0`` on
  (Eq. 14's λ_SDS);
* ``Scheduled.exponential(value, x0, x1, factor)`` -- ``value`` until ``x0``, then a smooth
  geometric decay to ``value · factor`` at ``x1`` (Stage I's learning rate over its budget).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

SHAPES = ("ramp", "drops", "halving", "exponential")


@dataclass(frozen=True)
class Scheduled:
    shape: str
    value0: float
    # ramp: (start_step, end_step, end_value); drops: the points and the factor; halving: (t0, k)
    points: tuple[float, ...] = ()
    factor: float = 1.0
    end_value: float | None = None

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"a scheduled value's shape is one of {', '.join(SHAPES)}, found {self.shape!r}")
        if self.shape == "ramp" and len(self.points) != 2:
            raise ValueError(f"a ramp needs [start_step, end_step], found {self.points!r}")
        if self.shape == "exponential":
            if len(self.points) != 2 or not self.points[0] < self.points[1]:
                raise ValueError(f"an exponential decay needs x0 < x1, found {self.points!r}")
            if self.factor <= 0:
                raise ValueError(f"an exponential decay's factor must be positive, found {self.factor}")
        if self.shape == "halving":
            if len(self.points) != 2:
                raise ValueError(f"a halving schedule needs (t0, k), found {self.points!r}")
            if self.points[1] <= 0:
                raise ValueError(f"halving interval k must be positive, found {self.points[1]}")

    # ----- constructors ---------------------------------------------------------------------
    @classmethod
    def constant(cls, value: float) -> "Scheduled":
        return cls("drops", float(value))

    @classmethod
    def ramp(cls, start_step: float, start_value: float, end_value: float, end_step: float) -> "Scheduled":
        return cls("ramp", float(start_value), (float(start_step), float(end_step)), end_value=float(end_value))

    @classmethod
    def drops(cls, value: float, at: tuple[float, ...] = (), factor: float = 0.1) -> "Scheduled":
        return cls("drops", float(value), tuple(sorted(float(a) for a in at)), float(factor))

    @classmethod
    def exponential(cls, value: float, x0: float, x1: float, factor: float) -> "Scheduled":
        return cls("exponential", float(value), (float(x0), float(x1)), float(factor))

    @classmethod
    def halving(cls, value: float, t0: float, k: float) -> "Scheduled":
        return cls("halving", float(value), (float(t0), float(k)), 0.5)

    @classmethod
    def parse(cls, value) -> "Scheduled":
        """A number (constant), ``[start_step, start_value, end_value, end_step]`` (ramp; a list,
        tuple or the string "[a, b, c, d]"), or a Scheduled."""
        if isinstance(value, Scheduled):
            return value
        if isinstance(value, (int, float)):
            return cls.constant(value)
        if isinstance(value, str):
            value = [float(v) for v in value.strip("[]() ").split(",")]
        if len(value) != 4:
            raise ValueError(f"a scheduled value is a number or [start_step, start_value, end_value, end_step], "
                             f"found {value!r}")
        a, b, c, d = (float(v) for v in value)
        return cls.ramp(a, b, c, d)

    # ----- evaluation ---------------------------------------------------------------------
    def value(self, x: float) -> float:
        if self.shape == "ramp":
            (x0, x1), v1 = self.points, self.end_value
            if x1 <= x0 or x <= x0:
                return self.value0 if x < x1 else v1
            t = min(1.0, (x - x0) / (x1 - x0))
            return self.value0 + t * (v1 - self.value0)
        if self.shape == "drops":
            return self.value0 * self.factor ** sum(x >= a for a in self.points)
        if self.shape == "exponential":
            x0, x1 = self.points
            t = min(1.0, max(0.0, (x - x0) / (x1 - x0)))
            return self.value0 * self.factor ** t
        t0, k = self.points  # halving
        if x < t0:
            return self.value0
        return self.value0 / 2.0 ** math.floor((x - t0) / k)

    __call__ = value
