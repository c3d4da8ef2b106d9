"""Skeletal animation in binary FBX files (``.fbx``), read as data.

What Mixamo downloads, and what Maya, MotionBuilder, 3ds Max, Unity and Blender export. The file is
parsed by ``fbx_binary`` (no FBX SDK, nothing run); this module reads its scene:

- **the skeleton**: the largest tree of skeleton models (``LimbNode``, ``Limb``, ``Root``), its
  joints in depth-first order; the models above its root (an armature ``Null``, a scene root turned
  to Y up or scaled) place it in the scene and may carry root motion;
- **each joint's transform**, as the FBX SDK and Maya compose it:
  ``T · Roff · Rp · Rpre · R · Rpost⁻¹ · Rp⁻¹ · Soff · Sp · S · Sp⁻¹``, with ``R`` the Euler
  ``Lcl Rotation`` in the model's ``RotationOrder`` and the pre/post rotations (Maya's joint orient)
  in XYZ order. As in Blender's importer, the pre/post rotations and the rotation order count where
  ``RotationActive`` is set;
- **the animation**: the first animation stack's first layer; each ``Lcl Translation`` /
  ``Lcl Rotation`` / ``Lcl Scaling`` curve node's X, Y, Z curves (key times in FBX ticks,
  46186158000 per second), sampled at the file's frame rate (``GlobalSettings`` ``TimeMode``, else
  the keys' spacing) between the first and last key: linearly, or held for constant keys; each Euler
  angle is interpolated on its own, as the SDK does. Cubic keys are read linearly between them
  (exact at the keys: Mixamo bakes a key per frame, Blender writes linear keys even when it thins
  them). Channels without a curve keep the model's value.

The rest pose is the file's bind pose (the skinning rest, written with a skinned mesh), else the
models' own (non-animated) transform values -- which some exporters (Blender's among them) set to
the pose of the frame the file was exported at; the clip's notes say which. Animated scale and the
translations of joints below the root are ignored with a note (bone lengths are the avatar's).
ASCII FBX and FBX before 7.0 are refused with a message saying how to re-export.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .clip import MotionClip, MotionFileError, read_motion_bytes
from .fbx_binary import FbxNode, is_ascii_fbx, parse_fbx
from .rig_clip import first_branch, rig_clip, role_joints, varies, wrapper_note
from .rotations import euler_to_matrix

TICKS_PER_SECOND = 46186158000
SKELETON_TYPES = ("LimbNode", "Limb", "Root")
ORDERS = ("XYZ", "XZY", "YZX", "YXZ", "ZXY", "ZYX", "XYZ")  # RotationOrder 0-6 (6: spheric XYZ, read as XYZ)
# GlobalSettings TimeMode -> frames per second (0: the SDK's default, 30; 14: CustomFrameRate)
TIME_MODES = {0: 30.0, 1: 120.0, 2: 100.0, 3: 60.0, 4: 50.0, 5: 48.0, 6: 30.0, 7: 30.0, 8: 30000 / 1001,
              9: 30000 / 1001, 10: 25.0, 11: 24.0, 12: 1000.0, 13: 24000 / 1001, 15: 96.0, 16: 72.0,
              17: 60000 / 1001, 18: 120000 / 1001}
_CHANNELS = ("Lcl Translation", "Lcl Rotation", "Lcl Scaling")
_CONSTANT, _CONSTANT_NEXT = 0x02, 0x100


def _props(node: FbxNode | None) -> dict[str, list]:
    """A ``Properties70`` block as name -> its values (after name, type, label and flags)."""
    out = {}
    block = node.find("Properties70") if node is not None else None
    for p in (block.find_all("P") if block is not None else []):
        if p.values and isinstance(p.values[0], str):
            out[p.values[0]] = p.values[4:]
    return out


def _vec(props: dict, name: str, default=(0.0, 0.0, 0.0)) -> np.ndarray:
    v = props.get(name)
    try:
        return np.array([float(x) for x in v[:3]], np.float64) if v and len(v) >= 3 else np.array(default, np.float64)
    except (TypeError, ValueError):
        return np.array(default, np.float64)


def _number(values) -> float | None:
    try:
        v = float(values[0])
    except (TypeError, ValueError, IndexError):
        return None
    return v if np.isfinite(v) else None


def _int(props: dict, name: str, default: int = 0) -> int:
    v = props.get(name)
    try:
        return int(v[0]) if v else default
    except (TypeError, ValueError):
        return default


def _object_name(value) -> str:
    """'Hips\\x00\\x01Model' (binary 7.x) or 'Model::Hips' -> 'Hips'."""
    text = str(value)
    if "\x00\x01" in text:
        return text.split("\x00\x01")[0]
    return text.split("::", 1)[1] if "::" in text else text


def euler(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """(..., 3, 3) of FBX Euler angles (..., 3) as (X, Y, Z) degrees; ``order`` "XYZ" turns about
    X first, then Y, then Z (``R = Rz Ry Rx``)."""
    idx = ["XYZ".index(a) for a in reversed(order)]
    return euler_to_matrix(np.asarray(angles_deg, np.float64)[..., idx], order[::-1])


class _Model:
    """A scene model's static transform properties and the local matrix they make."""

    def __init__(self, node: FbxNode) -> None:
        self.id = int(node.values[0])
        self.name = _object_name(node.values[1]) if len(node.values) > 1 else f"model {self.id}"
        self.kind = str(node.values[2]) if len(node.values) > 2 else ""
        p = _props(node)
        active = bool(_int(p, "RotationActive", 0))
        self.order = ORDERS[min(max(_int(p, "RotationOrder", 0), 0), 6)] if active else "XYZ"
        zero = np.zeros(3)
        self.pre = euler(_vec(p, "PreRotation"), "XYZ") if active else np.eye(3)
        self.post_inv = euler(_vec(p, "PostRotation"), "XYZ").T if active else np.eye(3)
        self.rot_offset, self.rot_pivot = _vec(p, "RotationOffset"), _vec(p, "RotationPivot")
        self.scale_offset, self.scale_pivot = _vec(p, "ScalingOffset"), _vec(p, "ScalingPivot")
        self.static = {"Lcl Translation": _vec(p, "Lcl Translation", zero), "Lcl Rotation": _vec(p, "Lcl Rotation", zero),
                       "Lcl Scaling": _vec(p, "Lcl Scaling", (1.0, 1.0, 1.0))}

    def rotation(self, r_deg: np.ndarray) -> np.ndarray:
        """(..., 3, 3) the node's rotation part ``Rpre R Rpost⁻¹`` for Euler angles (..., 3)."""
        return self.pre @ euler(r_deg, self.order) @ self.post_inv

    def matrix(self, t: np.ndarray, r_deg: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(..., 4, 4) the local matrix for translation, Euler angles and scale (..., 3) each."""
        t, r_deg, s = np.broadcast_arrays(t, r_deg, s)
        R = self.rotation(r_deg)
        A = R * s[..., None, :]
        # x -> R (S (x - Sp) + Sp + Soff - Rp) + Rp + Roff + T
        inner = s * (-self.scale_pivot) + self.scale_pivot + self.scale_offset - self.rot_pivot
        origin = np.einsum("...ij,...j->...i", R, inner) + self.rot_pivot + self.rot_offset + t
        M = np.broadcast_to(np.eye(4), t.shape[:-1] + (4, 4)).copy()
        M[..., :3, :3] = A
        M[..., :3, 3] = origin
        return M

    def rest_matrix(self) -> np.ndarray:
        return self.matrix(self.static["Lcl Translation"], self.static["Lcl Rotation"], self.static["Lcl Scaling"])


class _Curve:
    def __init__(self, path: Path, node: FbxNode) -> None:
        times, values = node.find("KeyTime"), node.find("KeyValueFloat") or node.find("KeyValueDouble")
        if times is None or values is None or not times.values or not values.values:
            raise MotionFileError(f"{path}: an animation curve ({node.values[0] if node.values else '?'}) has no keys")
        self.times = np.asarray(times.values[0], np.int64)
        self.values = np.asarray(values.values[0], np.float64)
        if self.times.ndim != 1 or self.times.shape != self.values.shape or len(self.times) == 0:
            raise MotionFileError(f"{path}: an animation curve has {np.size(self.times)} key times and "
                                  f"{np.size(self.values)} values")
        if not np.all(np.isfinite(self.values)):
            raise MotionFileError(f"{path}: an animation curve holds values that are not finite numbers")
        if np.any(np.diff(self.times) < 0):
            raise MotionFileError(f"{path}: an animation curve's key times go backwards")
        flags = node.find("KeyAttrFlags")
        counts = node.find("KeyAttrRefCount")
        self.constant = np.zeros(len(self.times), bool)  # held to the key (constant keys) ...
        self.constant_next = np.zeros(len(self.times), bool)  # ... or to the next key's value
        if flags is not None and counts is not None and flags.values and counts.values:
            f, c = np.asarray(flags.values[0]).ravel(), np.asarray(counts.values[0]).ravel()
            if len(f) == len(c) and np.all(c >= 0) and int(c.sum()) == len(self.times):
                per_key = np.repeat(f, c)
                self.constant = (per_key & _CONSTANT) != 0
                self.constant_next = (per_key & _CONSTANT_NEXT) != 0

    def sample(self, ticks: np.ndarray) -> np.ndarray:
        k = self.times
        if len(k) == 1:
            return np.full(len(ticks), self.values[0])
        i = np.clip(np.searchsorted(k, ticks, side="right") - 1, 0, len(k) - 2)
        span = np.maximum(k[i + 1] - k[i], 1).astype(np.float64)
        w = np.clip((ticks - k[i]) / span, 0.0, 1.0)
        hold = self.constant[i] & (w < 1.0)
        w = np.where(hold, 0.0, w)
        w = np.where(hold & self.constant_next[i], 1.0, w)
        return self.values[i] * (1.0 - w) + self.values[i + 1] * w


def _bind_pose(path: Path, objects: FbxNode) -> dict[int, np.ndarray]:
    """model id -> its world matrix (4,4) in the file's bind poses (the skinning rest pose)."""
    out = {}
    for pose in objects.find_all("Pose"):
        kind = pose.find("Type")
        if len(pose.values) < 3 or pose.values[2] != "BindPose" and not (kind and kind.values == ["BindPose"]):
            continue
        for pn in pose.find_all("PoseNode"):
            node, matrix = pn.find("Node"), pn.find("Matrix")
            if node is None or matrix is None or not node.values or not matrix.values:
                continue
            M = np.asarray(matrix.values[0], np.float64)
            if M.shape != (16,) or not np.all(np.isfinite(M)):
                raise MotionFileError(f"{path}: a bind pose matrix holds {M.size} values, not 16")
            out.setdefault(int(node.values[0]), M.reshape(4, 4).T)  # stored column by column
    return out


def read_fbx(path: str | os.PathLike, *, up: str | None = None, forward: str | None = None,
             metres_per_unit: float | None = None) -> MotionClip:
    """Reads a binary FBX file's skeleton and first animation into a ``MotionClip``. ``up`` /
    ``forward`` override the axes detected from the rest skeleton; ``metres_per_unit`` overrides the
    file's ``UnitScaleFactor`` (centimetres per unit)."""
    path = Path(path)
    data = read_motion_bytes(path)
    if is_ascii_fbx(data):
        raise MotionFileError(f"{path}: an ASCII FBX file; only binary FBX is read (export it as binary FBX, "
                              "or as glTF or BVH)")
    version, root = parse_fbx(path, data)
    try:
        return _read_scene(path, version, root, up, forward, metres_per_unit)
    except MotionFileError:
        raise
    except (IndexError, KeyError, TypeError, ValueError, OverflowError, ZeroDivisionError,
            np.linalg.LinAlgError) as exc:  # records of the wrong shape in a sound container
        raise MotionFileError(f"{path}: a malformed FBX scene ({type(exc).__name__}: {exc})") from None


def _read_scene(path: Path, version: int, root: FbxNode, up: str | None, forward: str | None,
                metres_per_unit: float | None) -> MotionClip:
    objects = root.find("Objects")
    if objects is None:
        raise MotionFileError(f"{path}: no Objects section in the FBX file")
    notes: list[str] = []
    models = {m.id: m for m in (_Model(n) for n in objects.find_all("Model")
                                if len(n.values) >= 3 and isinstance(n.values[0], int))}
    by_id = {int(n.values[0]): n for n in objects.children if n.values and isinstance(n.values[0], int)}
    links = [c.values for c in (root.find("Connections") or FbxNode("")).find_all("C") if len(c.values) >= 3]
    parent_of, children = {}, {}
    for v in links:
        if v[0] == "OO" and v[1] in models and (v[2] in models or v[2] == 0):  # not a skin cluster's link
            parent_of[v[1]] = v[2]
            children.setdefault(v[2], []).append(v[1])

    joints_set = {i for i, m in models.items() if m.kind in SKELETON_TYPES}
    if not joints_set:
        raise MotionFileError(f"{path}: no skeleton in the FBX file (no LimbNode models); expected an "
                              "animated character")

    def subtree(j):
        out, stack = [], [j]
        while stack:
            k = stack.pop()
            out.append(k)
            stack.extend(c for c in reversed(children.get(k, [])) if c in joints_set)
        return out

    roots = [j for j in joints_set if parent_of.get(j) not in joints_set]
    order = max((subtree(r) for r in roots), key=len)
    if len(order) < len(joints_set):
        notes.append(f"{len(joints_set) - len(order)} skeleton nodes outside the main skeleton's tree ignored")
    top, wrappers = first_branch(order[0], lambda j: [c for c in children.get(j, []) if c in joints_set],
                                 role_joints(order, [models[m].name for m in order]))
    if wrappers:
        order = subtree(top)
        notes.append(wrapper_note([models[m].name for m in wrappers], models[top].name))
    index = {m: k for k, m in enumerate(order)}
    J = len(order)
    names = [models[m].name for m in order]
    parents = np.array([index.get(parent_of.get(m), -1) if k else -1 for k, m in enumerate(order)])
    chain = []  # models above the skeleton's root, nearest first
    k = parent_of.get(order[0])
    while k in models and k not in chain:
        chain.append(k)
        k = parent_of.get(k)

    # ----- the animation: the first stack's first layer -----------------------------------
    stacks = objects.find_all("AnimationStack")
    if not stacks:
        raise MotionFileError(f"{path}: no animation in the FBX file (only a rest pose); export it with its animation")
    stack_id = int(stacks[0].values[0])
    if len(stacks) > 1:
        notes.append(f"{len(stacks)} animation stacks (takes): the first ({_object_name(stacks[0].values[1])!r}) is used")
    layers = [v[1] for v in links if v[0] == "OO" and v[2] == stack_id and v[1] in by_id
              and by_id[v[1]].name == "AnimationLayer"]
    if not layers:
        raise MotionFileError(f"{path}: the animation stack has no layer")
    if len(layers) > 1:
        notes.append(f"{len(layers)} animation layers: the first is used")
    curve_nodes = {v[1] for v in links if v[0] == "OO" and v[2] == layers[0] and v[1] in by_id
                   and by_id[v[1]].name == "AnimationCurveNode"}
    node_target = {}  # curve node -> (model, channel)
    for v in links:
        if v[0] == "OP" and len(v) >= 4 and v[1] in curve_nodes and v[2] in models and v[3] in _CHANNELS:
            node_target[v[1]] = (v[2], v[3])
    tracks = {}  # (model, channel) -> [curve or default value per axis]
    for v in links:
        if v[0] == "OP" and len(v) >= 4 and v[2] in node_target and v[1] in by_id and by_id[v[1]].name == "AnimationCurve":
            axis = {"d|X": 0, "d|Y": 1, "d|Z": 2}.get(v[3])
            if axis is not None:
                tracks.setdefault(node_target[v[2]], {})[axis] = _Curve(path, by_id[v[1]])
    for cn, target in node_target.items():  # the curve node's own values for axes without a curve
        defaults = _props(by_id[cn])
        for axis, key in enumerate(("d|X", "d|Y", "d|Z")):
            value = _number(defaults.get(key))
            if value is not None:
                tracks.setdefault(target, {}).setdefault(axis, value)
    # (model, channel) pairs whose curves change along the keys (exporters bake constant ones too)
    varying = {key for key, axes in tracks.items()
               if any(isinstance(c, _Curve) and varies(c.values) for c in axes.values())}
    in_use = set(order) | set(chain)
    curves = [c for (m, _), axes in tracks.items() if m in in_use for c in axes.values() if isinstance(c, _Curve)]
    if not any(m in index for (m, ch), axes in tracks.items() if any(isinstance(c, _Curve) for c in axes.values())):
        raise MotionFileError(f"{path}: the first animation moves none of the skeleton's joints")

    settings = _props(root.find("GlobalSettings"))
    mode = _int(settings, "TimeMode", -1)
    fps = float(settings["CustomFrameRate"][0]) if mode == 14 and settings.get("CustomFrameRate") else TIME_MODES.get(mode)
    allk = np.unique(np.concatenate([c.times for c in curves]))
    if fps is None or not np.isfinite(fps) or fps <= 0:
        steps = np.diff(allk)
        step = float(np.median(steps[steps > 0])) / TICKS_PER_SECOND if np.any(steps > 0) else 1.0 / 30.0
        fps = 1.0 / step
    fps = float(np.clip(fps, 1.0, 1000.0))
    t0, t1 = int(allk[0]), int(allk[-1])
    T = max(1, int(round((t1 - t0) / TICKS_PER_SECOND * fps)) + 1)
    ticks = t0 + np.round(np.arange(T) * (TICKS_PER_SECOND / fps)).astype(np.int64)

    def channel(m: int, name: str) -> np.ndarray:
        """(T, 3) a model's channel: its curves where it has them, else its static value."""
        out = np.broadcast_to(models[m].static[name], (T, 3)).copy()
        for axis, c in tracks.get((m, name), {}).items():
            out[:, axis] = c.sample(ticks) if isinstance(c, _Curve) else c
        return out

    def animated_matrix(m: int) -> np.ndarray:
        return models[m].matrix(channel(m, "Lcl Translation"), channel(m, "Lcl Rotation"), channel(m, "Lcl Scaling"))

    above_rest = np.eye(4)
    above = np.broadcast_to(np.eye(4), (T, 4, 4)).copy()
    for m in chain:
        above_rest = models[m].rest_matrix() @ above_rest
        above = animated_matrix(m) @ above
    if any(m in chain for m, _ in varying):
        notes.append("the nodes above the skeleton move: their motion is the root's")
    # the rest pose: the bind pose where the file has one (the models' own values are often the pose
    # of the frame the file was exported at), else the models' own values
    bind = _bind_pose(path, objects)
    rest_world = np.zeros((J, 4, 4))
    for k, m in enumerate(order):
        rest_world[k] = bind[m] if m in bind else \
            (above_rest if parents[k] < 0 else rest_world[parents[k]]) @ models[m].rest_matrix()
    in_bind = sum(m in bind for m in order)
    notes.append("rest pose: the bind pose" if in_bind == J else
                 f"rest pose: the bind pose for {in_bind} of {J} joints, the models' own values for the rest"
                 if in_bind else "rest pose: the models' own values (the file has no bind pose)")
    L = np.stack([models[m].rotation(channel(m, "Lcl Rotation")) for m in order], 1)
    root_t = animated_matrix(order[0])[:, :3, 3]
    scaled = sorted({models[m].name for m, ch in varying if m in index and ch == "Lcl Scaling"})
    if scaled:
        notes.append(f"animated scale of {len(scaled)} joint{'s' * (len(scaled) != 1)} ignored")
    moved = sorted({models[m].name for m, ch in varying if m in index and m != order[0] and ch == "Lcl Translation"})
    if moved:
        notes.append(f"translations of {len(moved)} non-root joints ignored: bone lengths are the avatar's")
    pivoted = [m for m in order[1:] if np.any(models[m].rot_pivot != 0) or np.any(models[m].rot_offset != 0)]
    if pivoted:
        notes.append(f"rotation pivots on {len(pivoted)} joint{'s' * (len(pivoted) != 1)}: their origins are kept "
                     "where the rest pose has them (bone lengths are the avatar's)")
    if not all(np.all(np.isfinite(a)) for a in (rest_world, L, above, root_t)):
        raise MotionFileError(f"{path}: the skeleton's transforms hold values that are not finite numbers")
    unit_cm = settings.get("UnitScaleFactor")
    try:
        cm = float(unit_cm[0]) if unit_cm else 1.0
    except (TypeError, ValueError):
        cm = 1.0
    unit = float(metres_per_unit) if metres_per_unit else (cm / 100.0 if np.isfinite(cm) and cm > 0 else 0.01)
    notes.append(f"FBX {version / 1000:.1f}, units {unit * 100:g} cm")
    return rig_clip(path, names, parents, rest_world, L, above, root_t, fps, up=up, forward=forward,
                    metres_per_unit=unit, fmt="FBX", notes=notes)
