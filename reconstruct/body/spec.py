"""Which body model and shape a scene uses, and the table of body backends that build it.

``BodySpec`` is hashable data (stored with scenes and runs); ``build_body`` turns it into a
``BodyModel`` through ``BACKENDS``: ``anny`` (the default, shipped with the ``anny`` package) and
``smpl`` (from model files the user supplies). The body package never imports the data package:
scenes carry a BodySpec, the body package builds from it."""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

from .base import BodyModel


def _build_anny(params: dict) -> BodyModel:
    from .anny_backend import AnnyBody

    spread = float(params.pop("leg_spread_deg", 5.0))
    return AnnyBody(params, leg_spread_deg=spread)


def _build_smpl(params: dict) -> BodyModel:
    from .smpl_backend import build_smpl_body

    return build_smpl_body(params)


BACKENDS: dict[str, Callable[[dict], BodyModel]] = {"anny": _build_anny, "smpl": _build_smpl}


@dataclass(frozen=True)
class BodySpec:
    """Which body model and shape: ``model`` (a key of ``BACKENDS``) and its parameters."""

    model: str = "anny"
    params: tuple = ()  # sorted (key, value) pairs so the spec is hashable

    @classmethod
    def anny(cls, phenotype: dict[str, float], leg_spread_deg: float = 5.0) -> "BodySpec":
        return cls("anny", tuple(sorted({**phenotype, "leg_spread_deg": leg_spread_deg}.items())))

    def build(self) -> BodyModel:
        return build_body(self)

    def to_dict(self) -> dict:
        return {"model": self.model, "params": dict(self.params)}

    @classmethod
    def from_dict(cls, d: dict) -> "BodySpec":
        return cls(str(d.get("model", "anny")), tuple(sorted(dict(d.get("params", {})).items())))


@lru_cache(maxsize=4)
def build_body(spec: BodySpec) -> BodyModel:
    backend = BACKENDS.get(spec.model)
    if backend is None:
        raise ValueError(f"unknown body model {spec.model!r}; available: {', '.join(repr(k) for k in BACKENDS)}")
    return backend(dict(spec.params))


def smpl_body_spec(betas=(), gender: str = "neutral", smpl_dir: str | os.PathLike | None = None) -> BodySpec:
    """The (hashable) BodySpec of an SMPL body: betas are kept as a text list."""
    from .smpl_backend import GENDERS, format_betas

    if gender not in GENDERS:
        raise ValueError(f"SMPL gender must be one of {GENDERS}, found {gender!r}")
    params = {"gender": gender, "betas": format_betas(betas)}
    if smpl_dir:
        params["smpl_dir"] = str(Path(smpl_dir).expanduser().resolve())
    return BodySpec("smpl", tuple(sorted(params.items())))
