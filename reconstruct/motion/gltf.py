"""Skeletal animation in glTF 2.0 files (``.glb`` binary or ``.gltf`` JSON), read as data.

What Blender, Ready Player Me, Mixamo-to-glTF converters and most game tools export: the first
skin's joints are the skeleton, the first animation drives them. Each joint's rest pose is its node's
own translation, rotation and scale (glTF's rest rotations need not be the identity, unlike BVH's),
and the nodes above the skeleton (an armature turned to Y up, scaled 0.01 from centimetres) place it
in the scene. The reader turns this into the ``MotionClip`` convention (identity rest rotations,
rest offsets in world axes): with R0 the rest world rotations and L(t) a joint's animated local
rotation, the clip's local rotation is ``R0_parent L(t) R0_joint^T``, and a joint's offset is its
rest translation carried into world axes by its parent's rest world matrix (scales included).

Samplers: LINEAR (rotations by slerp), STEP and CUBICSPLINE (its key values, linearly; noted) are
resampled at the keys' own rate. Animated scale and morph weights are ignored with a note; an
animated translation is used for the root only (bone lengths are the avatar's); nodes above the
skeleton that the animation moves (root motion put on the armature) move the root. Buffers come from
the GLB's binary chunk, from ``data:`` URIs, or from files next to a ``.gltf`` (never from a path
that leaves its folder, never from the network). Nothing in a glTF file is code.
"""

from __future__ import annotations

import base64
import json
import os
import struct
from pathlib import Path

import numpy as np

from .clip import MotionClip, MotionFileError, read_motion_bytes
from .rig_clip import first_branch, rig_clip, role_joints, varies, wrapper_note
from .rotations import quat_to_matrix, slerp

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_NORMALISED = {np.int8: 127.0, np.uint8: 255.0, np.int16: 32767.0, np.uint16: 65535.0}


def _container(path: Path, data: bytes) -> tuple[dict, bytes | None]:
    """(the glTF JSON, the GLB binary chunk or None)."""
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise MotionFileError(f"{path}: truncated GLB header")
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2:
            raise MotionFileError(f"{path}: GLB version {version}; expected 2 (glTF 2.0)")
        chunks, pos = {}, 12
        while pos + 8 <= min(length, len(data)):
            size, kind = struct.unpack_from("<II", data, pos)
            chunks.setdefault(kind, data[pos + 8:pos + 8 + size])
            pos += 8 + size + (-size % 4)
        if 0x4E4F534A not in chunks:
            raise MotionFileError(f"{path}: GLB without a JSON chunk")
        text, binary = chunks[0x4E4F534A], chunks.get(0x004E4942)
    else:
        text, binary = data, None
    try:
        doc = json.loads(text.decode("utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MotionFileError(f"{path}: not a glTF file (its JSON cannot be read: {exc})") from None
    if not isinstance(doc, dict) or str(doc.get("asset", {}).get("version", "")).split(".")[0] != "2":
        raise MotionFileError(f"{path}: not a glTF 2.0 file (asset.version is "
                              f"{doc.get('asset', {}).get('version') if isinstance(doc, dict) else None!r})")
    return doc, binary


class _Buffers:
    def __init__(self, path: Path, doc: dict, binary: bytes | None) -> None:
        self.path, self.doc, self.binary, self.cache = path, doc, binary, {}

    def buffer(self, i: int) -> bytes:
        if i in self.cache:
            return self.cache[i]
        b = self.doc["buffers"][i]
        uri = b.get("uri")
        if uri is None:
            if self.binary is None:
                raise MotionFileError(f"{self.path}: buffer {i} has no uri and the file has no binary chunk")
            data = self.binary
        elif uri.startswith("data:"):
            data = base64.b64decode(uri.split(",", 1)[1])
        else:
            folder = self.path.parent.resolve()
            target = (folder / uri).resolve()
            if "://" in uri or folder not in target.parents:
                raise MotionFileError(f"{self.path}: buffer {i} points outside the file's folder ({uri!r}); "
                                      "only files beside it are read")
            try:
                data = target.read_bytes()
            except OSError as exc:
                raise MotionFileError(f"{self.path}: buffer {i} ({uri}) cannot be read: {exc}") from None
        self.cache[i] = data
        return data

    def accessor(self, i: int) -> np.ndarray:
        """(count, width) float64 of accessor ``i``."""
        try:
            a = self.doc["accessors"][i]
            dtype = np.dtype(_COMPONENTS[a["componentType"]])
            width = _WIDTH[a["type"]]
            count = int(a["count"])
            view = self.doc["bufferViews"][a["bufferView"]]
            raw = self.buffer(view["buffer"])
            start = int(view.get("byteOffset", 0)) + int(a.get("byteOffset", 0))
            stride = int(view.get("byteStride", 0)) or dtype.itemsize * width
            if count and start + stride * (count - 1) + dtype.itemsize * width > len(raw):
                raise MotionFileError(f"{self.path}: accessor {i} reaches past the end of its buffer")
            out = np.ndarray((count, width), dtype, raw, start, (stride, dtype.itemsize)).astype(np.float64)
        except (KeyError, IndexError, TypeError) as exc:
            raise MotionFileError(f"{self.path}: accessor {i} is incomplete ({exc!r})") from None
        if a.get("normalized") and dtype.type in _NORMALISED:
            out = np.maximum(out / _NORMALISED[dtype.type], -1.0)
        if not np.all(np.isfinite(out)):
            raise MotionFileError(f"{self.path}: accessor {i} holds non-finite values")
        return out


def _rest_trs(node: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(translation (3,), rotation (3,3), scale (3,)) of a node at rest."""
    if "matrix" in node:
        M = np.asarray(node["matrix"], np.float64).reshape(4, 4).T  # column-major
        scale = np.linalg.norm(M[:3, :3], axis=0)
        return M[:3, 3].copy(), M[:3, :3] / np.where(scale > 0, scale, 1.0), scale
    q = np.asarray(node.get("rotation", (0.0, 0.0, 0.0, 1.0)), np.float64)
    return (np.asarray(node.get("translation", (0.0, 0.0, 0.0)), np.float64),
            quat_to_matrix(np.array([q[3], q[0], q[1], q[2]]) / np.linalg.norm(q)),
            np.asarray(node.get("scale", (1.0, 1.0, 1.0)), np.float64))


def _affine(t: np.ndarray, R: np.ndarray, s: np.ndarray) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = R * s[None, :]
    M[:3, 3] = t
    return M


def _sample(times: np.ndarray, keys: np.ndarray, values: np.ndarray, interpolation: str, rotation: bool) -> np.ndarray:
    """(len(times), width) of a channel's keys resampled at ``times`` (clamped to its key range)."""
    if interpolation == "CUBICSPLINE":
        values = values.reshape(len(keys), 3, -1)[:, 1]  # in-tangent, value, out-tangent
    if len(keys) == 1:
        return np.repeat(values[:1], len(times), 0)
    i = np.clip(np.searchsorted(keys, times, side="right") - 1, 0, len(keys) - 2)
    span = np.maximum(keys[i + 1] - keys[i], 1e-12)
    w = np.clip((times - keys[i]) / span, 0.0, 1.0)
    if interpolation == "STEP":
        w = np.where(w >= 1.0, 1.0, 0.0)
    if rotation:
        q0, q1 = values[i][:, [3, 0, 1, 2]], values[i + 1][:, [3, 0, 1, 2]]
        q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
        q1 = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
        return slerp(q0, q1, w)  # w, x, y, z
    return values[i] * (1 - w[:, None]) + values[i + 1] * w[:, None]


def read_gltf(path: str | os.PathLike, *, up: str | None = None, forward: str | None = None,
              metres_per_unit: float | None = None) -> MotionClip:
    """Reads the first animation of a glTF 2.0 file's first skin into a ``MotionClip``.
    ``up``/``forward`` override the axes detected from the rest skeleton (glTF's own are Y up, the
    model facing +Z); ``metres_per_unit`` overrides glTF's metres."""
    path = Path(path)
    data = read_motion_bytes(path)
    doc, binary = _container(path, data)
    nodes = doc.get("nodes") or []
    skins = doc.get("skins") or []
    anims = doc.get("animations") or []
    if not skins:
        raise MotionFileError(f"{path}: no skin (a skeleton of joints) in the file; expected a skinned, animated "
                              "character")
    if not anims:
        raise MotionFileError(f"{path}: no animation in the file (only a rest pose); export it with its animation")
    notes = []
    if len(skins) > 1:
        notes.append(f"{len(skins)} skins: the first one's skeleton is used")
    joints = [int(j) for j in skins[0].get("joints", [])]
    parent = {}
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            parent[int(c)] = i
    in_skin = set(joints)
    roots = [j for j in joints if parent.get(j) not in in_skin]
    if not roots:
        raise MotionFileError(f"{path}: the skin's joints form no tree")

    def subtree(j):
        out, stack = [], [j]
        while stack:
            k = stack.pop()
            out.append(k)
            stack.extend(int(c) for c in reversed(nodes[k].get("children", [])) if int(c) in in_skin)
        return out

    order = max((subtree(r) for r in roots), key=len)
    if len(order) < len(joints):
        notes.append(f"{len(joints) - len(order)} joints outside the main skeleton's tree ignored")
    top, wrappers = first_branch(order[0], lambda j: [int(c) for c in nodes[j].get("children", []) if int(c) in in_skin],
                                 role_joints(order, [str(nodes[n].get("name") or f"node{n}") for n in order]))
    if wrappers:
        order = subtree(top)
        label = [str(nodes[n].get("name") or f"node{n}") for n in wrappers + [top]]
        notes.append(wrapper_note(label[:-1], label[-1]))
    index = {node: k for k, node in enumerate(order)}
    J = len(order)
    names = tuple(str(nodes[n].get("name") or f"node{n}") for n in order)
    parents = np.array([index.get(parent.get(n), -1) if k else -1 for k, n in enumerate(order)])
    rest = [_rest_trs(nodes[n]) for n in order]
    # the nodes above the skeleton's root (an armature's axes and scale), nearest first; at rest here,
    # frame by frame below where the animation moves them (root motion put on the armature)
    chain = []
    k = parent.get(order[0])
    while k is not None:
        chain.append(k)
        k = parent.get(k)
    chain_rest = {k: _rest_trs(nodes[k]) for k in chain}
    above = np.eye(4)
    for k in chain:
        above = _affine(*chain_rest[k]) @ above
    world0 = np.zeros((J, 4, 4))
    for k in range(J):
        local = _affine(*rest[k])
        world0[k] = (above if parents[k] < 0 else world0[parents[k]]) @ local

    # ----- the animation ------------------------------------------------------------------
    anim = anims[0]
    if len(anims) > 1:
        notes.append(f"{len(anims)} animations: the first ({anim.get('name', 'unnamed')!r}) is used")
    bufs = _Buffers(path, doc, binary)
    samplers = anim.get("samplers", [])
    # (joint index, path) -> keys, values, interpolation; the same for the nodes above, by node
    tracks, above_tracks, key_times, interpolations, ignored = {}, {}, [], set(), set()
    for ch in anim.get("channels", []):
        target = ch.get("target", {})
        node, what = target.get("node"), target.get("path")
        if node not in index and node not in chain:
            continue
        try:
            s = samplers[ch["sampler"]]
        except (KeyError, IndexError, TypeError):
            raise MotionFileError(f"{path}: an animation channel names no sampler") from None
        if what == "weights" or what == "scale" and varies(bufs.accessor(s["output"])):
            ignored.add(what)
        if what not in ("rotation", "translation"):
            continue
        keys = bufs.accessor(s["input"])[:, 0]
        values = bufs.accessor(s["output"])
        interp = s.get("interpolation", "LINEAR")
        if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
            raise MotionFileError(f"{path}: unknown interpolation {interp!r}")
        width = 4 if what == "rotation" else 3
        expect = len(keys) * (3 if interp == "CUBICSPLINE" else 1)
        if values.shape != (expect, width) or np.any(np.diff(keys) < 0):
            who = names[index[node]] if node in index else nodes[node].get("name", f"node {node}")
            raise MotionFileError(f"{path}: animation channel for {who!r} {what}: {len(keys)} key "
                                  f"times and {values.shape[0]} values of width {values.shape[1]}")
        if node in index:
            tracks[(index[node], what)] = (keys, values, interp)
        else:
            above_tracks[(node, what)] = (keys, values, interp)
        key_times.append(keys)
        interpolations.add(interp)
    notes.extend(f"animated {what} ignored" for what in sorted(ignored))
    if not tracks:
        raise MotionFileError(f"{path}: the first animation moves none of the skeleton's joints")
    if "CUBICSPLINE" in interpolations:
        notes.append("cubic-spline keys resampled linearly between their values")
    allk = np.unique(np.concatenate(key_times))
    t0, t1 = float(allk[0]), float(allk[-1])
    steps = np.diff(allk)
    step = float(np.median(steps[steps > 1e-6])) if np.any(steps > 1e-6) else 1.0 / 30.0
    fps = float(np.clip(1.0 / step, 1.0, 240.0))
    T = max(1, int(round((t1 - t0) * fps)) + 1)
    times = t0 + np.arange(T) / fps

    def animated(channels, key, rest_value):
        """(T, 3, 3) rotations or (T, 3) translations of ``channels[key]`` (key: (node, path)), its
        rest value where the animation has none."""
        if key not in channels:
            return np.broadcast_to(rest_value, (T,) + np.shape(rest_value))
        keys, values, interp = channels[key]
        rotation = key[1] == "rotation"
        out = _sample(times, keys, values, interp, rotation=rotation)
        return quat_to_matrix(out) if rotation else out

    # the nodes above the skeleton frame by frame (fixed unless the animation moves them)
    above_t = np.broadcast_to(np.eye(4), (T, 4, 4)).copy()
    for k in chain:
        t_rest, R_rest, s_rest = chain_rest[k]
        M = np.broadcast_to(np.eye(4), (T, 4, 4)).copy()
        M[:, :3, :3] = animated(above_tracks, (k, "rotation"), R_rest) * s_rest[None, None, :]
        M[:, :3, 3] = animated(above_tracks, (k, "translation"), t_rest)
        above_t = M @ above_t
    if any(varies(values) for _, values, _ in above_tracks.values()):
        notes.append("the nodes above the skeleton move: their motion is the root's")
    L = np.stack([animated(tracks, (k, "rotation"), rest[k][1]) for k in range(J)], 1)
    tr = animated(tracks, (0, "translation"), rest[0][0])
    moved = sorted({names[k] for (k, what), (_, values, _) in tracks.items()
                    if what == "translation" and k != 0 and varies(values)})
    if moved:
        notes.append(f"translations of {len(moved)} non-root joints ignored: bone lengths are the avatar's")
    return rig_clip(path, names, parents, world0, L, above_t, tr, fps, up=up, forward=forward,
                    metres_per_unit=metres_per_unit or 1.0, fmt="glTF", notes=notes)
