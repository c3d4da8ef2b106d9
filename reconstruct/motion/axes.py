"""Axes and units of a source skeleton: which way is up and which way it faces, and its size."""

from __future__ import annotations

import itertools

import numpy as np

from .roles import find_roles

_AXIS_NAMES = {"+X": (0, 1.0), "-X": (0, -1.0), "+Y": (1, 1.0), "-Y": (1, -1.0), "+Z": (2, 1.0), "-Z": (2, -1.0)}


def axis_vector(name: str) -> np.ndarray:
    name = name.strip().upper()
    if name in ("X", "Y", "Z"):
        name = "+" + name
    if name not in _AXIS_NAMES:
        raise ValueError(f"axis must be one of {', '.join(_AXIS_NAMES)}, found {name!r}")
    k, s = _AXIS_NAMES[name]
    v = np.zeros(3)
    v[k] = s
    return v


def snap_to_axis(v: np.ndarray, exclude: np.ndarray | None = None) -> np.ndarray:
    """The signed coordinate axis nearest to ``v`` (optionally not along ``exclude``)."""
    v = np.asarray(v, np.float64).copy()
    if exclude is not None:
        v[np.argmax(np.abs(exclude))] = 0.0
    k = int(np.argmax(np.abs(v)))
    out = np.zeros(3)
    out[k] = 1.0 if v[k] >= 0 else -1.0
    return out


def frame_to_body(up: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """(3,3) rotation taking ``up`` to +Z and ``forward`` (where the skeleton faces) to -Y."""
    up = up / np.linalg.norm(up)
    forward = forward - (forward @ up) * up
    forward /= np.linalg.norm(forward)
    left = np.cross(up, forward)  # in body axes: Z x -Y = +X, the body's left
    src = np.stack([left, -forward, up], 1)  # columns: source vectors of +X, +Y, +Z
    return src.T


def detect_rest_axes(names, positions: np.ndarray, naming: str = "bvh") -> tuple[np.ndarray, np.ndarray, str]:
    """(up, forward, how) of a rest skeleton, snapped to coordinate axes. Up points from the feet
    (or hips) to the head (or neck); left from the right side to the left (hips, shoulders);
    forward = left x up. Falls back on BVH's usual Y up, facing +Z."""
    roles = find_roles(names, naming)
    up = left = None
    top = next((roles[r] for r in ("head", "neck") if r in roles), None)
    bottom = [roles[r] for r in ("foot_l", "foot_r") if r in roles] or ([roles["hips"]] if "hips" in roles else [])
    if top is not None and bottom:
        d = positions[top] - positions[bottom].mean(0)
        if np.linalg.norm(d) > 1e-9:
            up = snap_to_axis(d)
    for a, b in (("upperleg_l", "upperleg_r"), ("upperarm_l", "upperarm_r"), ("clavicle_l", "clavicle_r"),
                 ("hand_l", "hand_r"), ("foot_l", "foot_r")):
        if a in roles and b in roles:
            d = positions[roles[a]] - positions[roles[b]]
            if np.linalg.norm(d) > 1e-9 and (up is None or abs(d @ up) < 0.9 * np.linalg.norm(d)):
                left = d
                break
    if up is None or left is None:
        return np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), "assumed (Y up, facing +Z)"
    left = snap_to_axis(left, exclude=up)
    forward = np.cross(left, up)
    return up, forward, "detected from the rest skeleton"


def skeleton_axes(source, names, positions: np.ndarray, up: str | None = None,
                  forward: str | None = None) -> tuple[np.ndarray, np.ndarray, str, np.ndarray]:
    """(up, forward, how, rest_to_body) of a file's rest skeleton: detected (``detect_rest_axes``)
    unless ``up``/``forward`` ("+Y", "-Z", ...) are given; raises ``MotionFileError`` naming
    ``source`` when the two are not perpendicular."""
    from .clip import MotionFileError

    up_v, fwd_v, how = detect_rest_axes(names, positions, "bvh")
    if up is not None or forward is not None:
        up_v = axis_vector(up) if up is not None else up_v
        fwd_v = axis_vector(forward) if forward is not None else np.cross(np.cross(up_v, fwd_v), up_v)
        how = "given"
    if abs(up_v @ fwd_v) > 1e-6 or np.linalg.norm(fwd_v) < 1e-9:
        raise MotionFileError(f"{source}: up {up_v} and forward {fwd_v} axes must be perpendicular")
    return up_v, fwd_v, how, frame_to_body(up_v, fwd_v)


def segment_length(positions: np.ndarray, chain: list[int]) -> float:
    return float(sum(np.linalg.norm(positions[b] - positions[a]) for a, b in itertools.pairwise(chain)))


def leg_length(positions: np.ndarray, roles: dict[str, int]) -> float | None:
    """Mean over the sides of hip -> knee -> ankle, or None when a side's joints are missing."""
    lengths = []
    for s in ("l", "r"):
        keys = (f"upperleg_{s}", f"lowerleg_{s}", f"foot_{s}")
        if all(k in roles for k in keys):
            lengths.append(segment_length(positions, [roles[k] for k in keys]))
    lengths = [x for x in lengths if x > 1e-9]
    return float(np.mean(lengths)) if lengths else None


def guess_metres_per_unit(positions: np.ndarray, roles: dict[str, int], up: np.ndarray) -> float:
    """Units from the leg (about 0.8 m) or the height (about 1.7 m): metres, centimetres,
    millimetres or inches."""
    leg = leg_length(positions, roles)
    if leg is not None:
        size, metres = leg, 0.8
    else:
        h = positions @ up
        size, metres = float(h.max() - h.min()), 1.6
    if size <= 0:
        return 1.0
    candidates = (1.0, 0.01, 0.001, 0.0254)
    return min(candidates, key=lambda u: abs(np.log(size * u / metres)))
