"""One config layer for every settings dataclass (Stage I, Stage II, the avatar).

Values from outside -- ``--set KEY=VALUE`` on the command line, a checkpoint's or ``run.json``'s
JSON -- are converted by each field's *type annotation*, not guessed from its default:
``int`` ("4" -> 4, "4.0" is an error), ``float``, ``bool`` (1/0, true/false, yes/no, on/off),
``str``, ``X | None`` ("none" or "" -> None), ``tuple[float, ...]`` ("1,2" or "[1, 2]") and nested
settings dataclasses (``avatar.hidden=64``). Unknown keys and bad values are errors that name the
setting and its type.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any

NONE_WORDS = ("none", "null", "")
TRUE_WORDS = ("1", "true", "yes", "on")
FALSE_WORDS = ("0", "false", "no", "off")


def _type_name(tp) -> str:
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def convert(value: Any, tp, name: str) -> Any:
    """``value`` (a string from the command line, or a JSON value) as type ``tp``; ValueError
    naming ``name`` and the type when it does not convert."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if value is None or (isinstance(value, str) and value.strip().lower() in NONE_WORDS):
            if type(None) in args:
                return None
        if len(inner) == 1:
            return convert(value, inner[0], name)
        raise ValueError(f"{name}: unsupported setting type {_type_name(tp)}")
    try:
        if origin is tuple:
            items = value
            if isinstance(value, str):
                text = value.strip().strip("[]()")
                items = [v for v in (s.strip() for s in text.split(",")) if v] if text else []
            if not isinstance(items, (list, tuple)):
                raise TypeError
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(convert(v, args[0], name) for v in items)
            if len(items) != len(args):
                raise ValueError(f"{name}: expected {len(args)} values ({_type_name(tp)}), found {len(items)}")
            return tuple(convert(v, a, name) for v, a in zip(items, args))
        if tp is bool:
            if isinstance(value, bool):
                return value
            if isinstance(value, str) and value.strip().lower() in TRUE_WORDS + FALSE_WORDS:
                return value.strip().lower() in TRUE_WORDS
            if isinstance(value, int) and value in (0, 1):
                return bool(value)
            raise TypeError
        if tp is int:
            if isinstance(value, bool):
                raise TypeError
            if isinstance(value, float):
                if not value.is_integer():
                    raise TypeError
                return int(value)
            return int(value)
        if tp is float:
            if isinstance(value, bool):
                raise TypeError
            return float(value)
        if tp is str:
            if not isinstance(value, str):
                raise TypeError
            return value
        if dataclasses.is_dataclass(tp):
            if isinstance(value, tp):
                return value
            if isinstance(value, dict):
                return from_dict(tp, value, name)
            raise TypeError
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ValueError) and str(exc).startswith(f"{name}:"):
            raise
        raise ValueError(f"{name}: expected {_type_name(tp)}, found {value!r}") from None
    return value


def from_dict(cls, d: dict, what: str):
    """A settings dataclass from a dict (``dataclasses.asdict`` / JSON): every value converted by
    its field's type, unknown keys an error naming them."""
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - fields)
    if unknown:
        raise ValueError(f"unknown {what} settings {unknown}")
    hints = _hints(cls)
    return cls(**{k: convert(v, hints[k], f"{what} setting {k!r}") for k, v in d.items()})


def to_dict(config) -> dict:
    return dataclasses.asdict(config)


def known_keys(cls, prefix: str = "") -> list[str]:
    """Every settable key of ``cls``, nested dataclasses as ``name.field``."""
    hints = _hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            out.extend(known_keys(tp, f"{prefix}{f.name}."))
        else:
            out.append(prefix + f.name)
    return out


def parse_overrides(cls, items: list[str] | None, what: str, flag: str = "--set") -> dict:
    """``KEY=VALUE`` strings as a dict of converted values for ``cls`` (nested keys ``a.b`` as
    nested dicts); errors name the flag, the key and the expected type."""
    hints = _hints(cls)
    out: dict = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"{flag} expects KEY=VALUE, found {item!r}")
        key, text = item.split("=", 1)
        key = key.strip()
        target, tps, path = out, hints, key.split(".")
        owner = cls
        for part in path[:-1]:
            tp = tps.get(part)
            if tp is None or not dataclasses.is_dataclass(tp):
                raise ValueError(f"{flag}: unknown {what} setting {key!r}; known: {', '.join(known_keys(cls))}")
            target = target.setdefault(part, {})
            tps, owner = _hints(tp), tp
        leaf = path[-1]
        if leaf not in tps or dataclasses.is_dataclass(tps[leaf]) or leaf not in {f.name for f in dataclasses.fields(owner)}:
            raise ValueError(f"{flag}: unknown {what} setting {key!r}; known: {', '.join(known_keys(cls))}")
        target[leaf] = convert(text, tps[leaf], f"{flag} {key} ({what} setting of type {_type_name(tps[leaf])})")
    return out


def with_overrides(config, overrides: dict):
    """A copy of ``config`` with ``overrides`` (as from ``parse_overrides``) applied; nested
    dataclasses are updated field by field. The dataclass checks its values on construction."""
    changes = {}
    for k, v in overrides.items():
        current = getattr(config, k)
        changes[k] = with_overrides(current, v) if isinstance(v, dict) and dataclasses.is_dataclass(current) else v
    return dataclasses.replace(config, **changes)
