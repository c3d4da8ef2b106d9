"""Binary FBX files built byte by byte for the motion tests (no FBX SDK): a record writer, and a rig
written the way Maya and MotionBuilder write them (``write_joint_orient_fbx``).

``scripts/make_fbx_fixtures.py`` has Blender import what ``write_joint_orient_fbx`` writes and
stores where Blender puts every joint in every frame (``tests/data/fbx/joint_orient.blender.npz``):
the reference the reader is checked against, independent of this writer's own arithmetic.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

try:
    from motion_files import SKELETON
except ImportError:  # imported from scripts/ with tests/ on the path
    from tests.motion_files import SKELETON  # type: ignore

MAGIC = b"Kaydara FBX Binary  \x00"
TICKS = 46186158000


class Rec:
    """One FBX record: name, values (int -> 'L' unless wrapped, float -> 'D', str -> 'S', bytes -> 'R',
    numpy arrays -> typed arrays) and children."""

    def __init__(self, name: str, *values, children=None) -> None:
        self.name, self.values, self.children = name, list(values), list(children or [])


class I32(int):
    pass


class F32(float):
    pass


def _value(v, compress: bool) -> bytes:
    if isinstance(v, bool):
        return b"C" + struct.pack("<?", v)
    if isinstance(v, I32):
        return b"I" + struct.pack("<i", v)
    if isinstance(v, int):
        return b"L" + struct.pack("<q", v)
    if isinstance(v, F32):
        return b"F" + struct.pack("<f", v)
    if isinstance(v, float):
        return b"D" + struct.pack("<d", v)
    if isinstance(v, str):
        raw = v.encode()
        return b"S" + struct.pack("<I", len(raw)) + raw
    if isinstance(v, bytes):
        return b"R" + struct.pack("<I", len(v)) + v
    a = np.asarray(v)
    code = {np.dtype(np.float32): b"f", np.dtype(np.float64): b"d", np.dtype(np.int64): b"l",
            np.dtype(np.int32): b"i"}[a.dtype]
    raw = np.ascontiguousarray(a, a.dtype.newbyteorder("<")).tobytes()
    if compress:
        packed = zlib.compress(raw)
        return code + struct.pack("<III", a.size, 1, len(packed)) + packed
    return code + struct.pack("<III", a.size, 0, len(raw)) + raw


def _record(rec: Rec, offset: int, wide: bool, compress: bool) -> bytes:
    head_fmt = "<QQQB" if wide else "<IIIB"
    head_size = struct.calcsize(head_fmt)
    values = b"".join(_value(v, compress) for v in rec.values)
    name = rec.name.encode()
    body = bytearray()
    start = offset + head_size + len(name) + len(values)
    if rec.children:
        for c in rec.children:
            body += _record(c, start + len(body), wide, compress)
        body += bytes(head_size)
    end = start + len(body)
    return struct.pack(head_fmt, end, len(rec.values), len(values), len(name)) + name + values + bytes(body)


def fbx_bytes(records: list[Rec], version: int = 7400, compress: bool = True) -> bytes:
    wide = version >= 7500
    out = bytearray(MAGIC + b"\x1a\x00" + struct.pack("<I", version))
    for r in records:
        out += _record(r, len(out), wide, compress)
    out += bytes(25 if wide else 13)
    out += bytes(160)  # the footer's padding and magic, which readers skip
    return bytes(out)


def P(name: str, kind: str, label: str, flags: str, *values) -> Rec:
    """A property as FBX 7 writes it: name, type, label, flags ('A': animatable), values."""
    return Rec("P", name, kind, label, flags, *values)


def props(*ps: Rec) -> Rec:
    return Rec("Properties70", children=list(ps))


def euler_xyz(angles_deg, order: str = "XYZ") -> np.ndarray:
    """FBX Euler angles (X, Y, Z degrees) as a matrix; ``order`` 'XYZ' turns about X first."""
    mats = {}
    for k, axis in enumerate("XYZ"):
        a = np.radians(angles_deg[k])
        c, s = np.cos(a), np.sin(a)
        mats[axis] = {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
                      "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
                      "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]
    R = np.eye(3)
    for axis in order:
        R = mats[axis] @ R
    return R


ORDER_CODES = {"XYZ": 0, "XZY": 1, "YZX": 2, "YXZ": 3, "ZXY": 4, "ZYX": 5}


def scene(models: list[dict], frames: int, fps: float, *, up_axis: int = 1, unit_cm: float = 1.0,
          time_mode: int = 14, anim_name: str = "Take 001", key_flags: int = 0x4 | 0x8,
          extra_objects=(), extra_links=()) -> list[Rec]:
    """The records of a scene. ``models``: dicts with ``name``, ``kind`` ('Null' / 'LimbNode'),
    ``parent`` (index or None), ``props`` (list of P records) and ``curves``: {'Lcl Rotation':
    (frames, 3) values, ...} keyed at every frame."""
    ids = iter(range(1000, 10 ** 6))
    objects, links = [], []
    model_ids = []
    for m in models:
        mid = next(ids)
        model_ids.append(mid)
        objects.append(Rec("Model", mid, f"{m['name']}\x00\x01Model", m["kind"],
                           children=[Rec("Version", I32(232)), props(*m.get("props", []))]))
    for m, mid in zip(models, model_ids):
        links.append(Rec("C", "OO", mid, model_ids[m["parent"]] if m["parent"] is not None else 0))
    stack, layer = next(ids), next(ids)
    objects.append(Rec("AnimationStack", stack, f"{anim_name}\x00\x01AnimStack", "", children=[props(
        P("LocalStop", "KTime", "Time", "", int(round((frames - 1) * TICKS / fps))))]))
    objects.append(Rec("AnimationLayer", layer, "BaseLayer\x00\x01AnimLayer", ""))
    links.append(Rec("C", "OO", layer, stack))
    times = np.round(np.arange(frames) * (TICKS / fps)).astype(np.int64)
    for m, mid in zip(models, model_ids):
        for channel, values in m.get("curves", {}).items():
            cn = next(ids)
            tag = {"Lcl Translation": "T", "Lcl Rotation": "R", "Lcl Scaling": "S"}[channel]
            objects.append(Rec("AnimationCurveNode", cn, f"{tag}\x00\x01AnimCurveNode", "", children=[props(
                P("d|X", "Number", "", "A", float(values[0, 0])), P("d|Y", "Number", "", "A", float(values[0, 1])),
                P("d|Z", "Number", "", "A", float(values[0, 2])))]))
            links.append(Rec("C", "OO", cn, layer))
            links.append(Rec("C", "OP", cn, mid, channel))
            for axis in range(3):
                cid = next(ids)
                objects.append(Rec("AnimationCurve", cid, "\x00\x01AnimCurve", "", children=[
                    Rec("Default", float(values[0, axis])), Rec("KeyVer", I32(4008)),
                    Rec("KeyTime", times), Rec("KeyValueFloat", np.asarray(values[:, axis], np.float32)),
                    Rec("KeyAttrFlags", np.array([key_flags], np.int32)),
                    Rec("KeyAttrDataFloat", np.zeros(4, np.float32)),
                    Rec("KeyAttrRefCount", np.array([frames], np.int32))]))
                links.append(Rec("C", "OP", cid, cn, "d|" + "XYZ"[axis]))
    objects.extend(extra_objects)
    links.extend(extra_links)
    settings = Rec("GlobalSettings", children=[Rec("Version", I32(1000)), props(
        P("UpAxis", "int", "Integer", "", I32(up_axis)), P("UpAxisSign", "int", "Integer", "", I32(1)),
        P("FrontAxis", "int", "Integer", "", I32(2 if up_axis == 1 else 1)),
        P("FrontAxisSign", "int", "Integer", "", I32(1 if up_axis == 1 else -1)),
        P("CoordAxis", "int", "Integer", "", I32(0)), P("CoordAxisSign", "int", "Integer", "", I32(1)),
        P("UnitScaleFactor", "double", "Number", "", float(unit_cm)),
        P("TimeMode", "enum", "", "", I32(time_mode)), P("CustomFrameRate", "double", "Number", "", float(fps)))])
    header = Rec("FBXHeaderExtension", children=[Rec("FBXHeaderVersion", I32(1003)), Rec("FBXVersion", I32(7400)),
                                                 Rec("Creator", "WonderHuman Studio test writer")])
    definitions = Rec("Definitions", children=[Rec("Version", I32(100)), Rec("Count", I32(len(objects)))])
    return [header, settings, definitions, Rec("Objects", children=objects), Rec("Connections", children=links)]


# ----- a Maya-style rig of the test skeleton ------------------------------------------------------
FRAMES, FPS = 10, 24.0
# joints turned in another Euler order (no pre-rotation on these: readers differ on the order of a
# pre-rotation beside a non-XYZ order)
ORDERS = {"LeftArm": "ZXY", "RightForeArm": "YZX", "LeftUpLeg": "ZYX", "Neck": "XZY", "Spine": "YXZ"}
POST = ("LeftForeArm", "RightLeg", "Head")  # joints with a PostRotation as well
PIVOT = {"RightArm": (1.5, -0.5, 2.0)}  # a rotation pivot (not at the joint)


def joint_orient_rig(seed: int = 11, prefix: str = "") -> tuple[list[dict], dict]:
    """The test skeleton (cm, Y up, T-pose) as Maya writes a rig: every joint oriented by a
    PreRotation (its joint orient) and at rest with zero Lcl Rotation, some joints in other Euler
    orders, some with a PostRotation, one with a rotation pivot; an 'Armature' Null above the root
    turned by 90 degrees about X and scaled by 2, standing the Y-up skeleton up in the scene's Z-up
    world (``GlobalSettings`` UpAxis Z, as 3ds Max writes). Returns (models, the world rest positions)."""
    rng = np.random.default_rng(seed)
    names = [n for n, _, _ in SKELETON]
    index = {n: k + 1 for k, n in enumerate(names)}
    world_rest = {}
    for n, parent, off in SKELETON:
        world_rest[n] = np.array(off, float) + (world_rest[parent] if parent else 0.0)
    arm_rot, arm_scale = (90.0, 0.0, 0.0), 2.0
    A = euler_xyz(arm_rot) * arm_scale
    models = [{"name": "Armature", "kind": "Null", "parent": None, "props": [
        P("Lcl Rotation", "Lcl Rotation", "", "A", *map(float, arm_rot)),
        P("Lcl Scaling", "Lcl Scaling", "", "A", arm_scale, arm_scale, arm_scale)]}]
    R0 = {}  # each joint's world rotation at rest, relative to the armature
    for n, parent, off in SKELETON:
        order = ORDERS.get(n, "XYZ")
        pre = np.zeros(3) if n in ORDERS else rng.uniform(-60, 60, 3)
        post = rng.uniform(-40, 40, 3) if n in POST else np.zeros(3)
        Rpre, Rpost = euler_xyz(pre), euler_xyz(post)
        parent_R = R0[parent] if parent else np.eye(3)
        R0[n] = parent_R @ Rpre @ Rpost.T
        # the joint's origin in its parent's frame, where the skeleton's offset (in the armature's
        # frame) lands it
        t = parent_R.T @ np.array(off, float)
        pivot = np.array(PIVOT.get(n, (0.0, 0.0, 0.0)))
        # x -> R (x - Rp) + Rp + T: at rest R = Rpre Rpost⁻¹, so T = t - Rp + Rpre Rpost⁻¹ Rp
        T = t - pivot + Rpre @ Rpost.T @ pivot
        frames = FRAMES
        rot = rng.uniform(-35.0, 35.0, (frames, 3))
        rot[0] = 0.0  # the first frame at rest
        curves = {"Lcl Rotation": rot}
        if parent is None:
            path = np.stack([3 * np.sin(np.arange(frames) / 2), np.zeros(frames), 4.0 * np.arange(frames)], 1)
            curves["Lcl Translation"] = T + path
        ps = [P("RotationActive", "bool", "", "", I32(1)), P("Lcl Translation", "Lcl Translation", "", "A", *map(float, T)),
              P("PreRotation", "Vector3D", "Vector", "", *map(float, pre)),
              P("PostRotation", "Vector3D", "Vector", "", *map(float, post)),
              P("RotationOrder", "enum", "", "", I32(ORDER_CODES[order])),
              P("RotationPivot", "Vector3D", "Vector", "", *map(float, pivot))]
        models.append({"name": prefix + n, "kind": "LimbNode", "parent": index[parent] if parent else 0,
                       "props": ps, "curves": curves})
    return models, {n: A @ p for n, p in world_rest.items()}


def write_joint_orient_fbx(path: Path, version: int = 7500, prefix: str = "") -> Path:
    """The rig of ``joint_orient_rig``; ``prefix`` goes before every joint's name (Mixamo's
    'mixamorig:')."""
    models, _ = joint_orient_rig(prefix=prefix)
    Path(path).write_bytes(fbx_bytes(scene(models, FRAMES, FPS, up_axis=2), version=version))
    return Path(path)
