"""The operations an edit applies to its texel mask (plain, frozen dataclasses; their ``name`` and
``params()`` are what the edits file stores).

- ``PaintSeen`` / ``PaintUnseen``: overrides of the visibility flags Stage II uses (view selection,
  propagated appearance, unseen-normal targets) and the visibility render mode shows.
- ``Lock``: the Gaussians keep the attributes they decode to now, whatever further training of
  either stage does to the shared decoder and feature map (the model's parameters at lock time
  are kept with the edit and decode those texels).
- ``Erase``: gone from renders (opacity 0) and from snapshots and exports (rows dropped).
- ``Recolour``: hue rotation (degrees), saturation and brightness (value) factors in HSV.
- ``Redo``: the region painted unseen and its colour reset to the prior's appearance (the Stage II
  plan's propagated pseudo-colours), as a per-texel logit offset over the decoded colour, so
  guidance steps train it on from there.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Op:
    name = ""

    def params(self) -> dict:
        return {}

    def describe(self) -> str:
        return self.name


@dataclass(frozen=True)
class PaintSeen(Op):
    name = "seen"


@dataclass(frozen=True)
class PaintUnseen(Op):
    name = "unseen"


@dataclass(frozen=True)
class Lock(Op):
    name = "lock"


@dataclass(frozen=True)
class Erase(Op):
    name = "erase"


@dataclass(frozen=True)
class Recolour(Op):
    name = "recolour"
    hue: float = 0.0  # degrees added to the hue
    saturation: float = 1.0  # factor
    value: float = 1.0  # factor (brightness)

    def __post_init__(self) -> None:
        for k in ("hue", "saturation", "value"):
            v = getattr(self, k)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or v != v or abs(v) == float("inf"):
                raise ValueError(f"recolour {k} must be a finite number, found {v!r}")
        if self.saturation < 0 or self.value < 0:
            raise ValueError(f"recolour saturation and value are factors >= 0, found {self.saturation}, {self.value}")

    def params(self) -> dict:
        return {"hue": float(self.hue), "saturation": float(self.saturation), "value": float(self.value)}

    def describe(self) -> str:
        return f"recolour:{self.hue:g},{self.saturation:g},{self.value:g}"


@dataclass(frozen=True)
class Redo(Op):
    name = "redo"


OPS: dict[str, type[Op]] = {c.name: c for c in (PaintSeen, PaintUnseen, Lock, Erase, Recolour, Redo)}
OP_HELP = "erase|lock|seen|unseen|redo|recolour:HUE_DEG,SAT,VALUE"


def op_from_params(name: str, params: dict) -> Op:
    """The op a stored entry names (``ValueError`` for an unknown name or bad parameters)."""
    if name not in OPS:
        raise ValueError(f"unknown edit operation {name!r} (one of {', '.join(OPS)})")
    cls = OPS[name]
    if not isinstance(params, dict):
        raise ValueError(f"{name}: params must be an object, found {type(params).__name__}")
    if cls is Recolour:
        unknown = set(params) - {"hue", "saturation", "value"}
        if unknown:
            raise ValueError(f"recolour: unknown params {sorted(unknown)}")
        return Recolour(**params)
    if params:
        raise ValueError(f"{name} takes no params, found {sorted(params)}")
    return cls()


def parse_op(text: str) -> Op:
    """``erase``, ``lock``, ``seen``, ``unseen``, ``redo`` or ``recolour:H,S,V`` (hue degrees,
    saturation factor, value factor; ``recolor`` is accepted too)."""
    name, _, rest = text.strip().partition(":")
    name = "recolour" if name == "recolor" else name
    if name not in OPS:
        raise ValueError(f"--op {text!r}: expected {OP_HELP}")
    if name != "recolour":
        if rest:
            raise ValueError(f"--op {text!r}: {name} takes no arguments")
        return OPS[name]()
    try:
        vals = [float(x) for x in rest.split(",")] if rest else []
    except ValueError:
        raise ValueError(f"--op {text!r}: recolour needs numbers HUE_DEG,SAT,VALUE") from None
    if len(vals) != 3:
        raise ValueError(f"--op {text!r}: recolour needs three numbers HUE_DEG,SAT,VALUE (e.g. recolour:30,1,0.8)")
    return Recolour(*vals)
