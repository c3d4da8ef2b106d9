"""BVH (Biovision Hierarchy) files read as data: HIERARCHY and MOTION sections.

Supported: one ROOT; JOINT and End Site; OFFSET; CHANNELS with any subset and order of
X/Y/Z position and rotation channels on any joint. Rotation channels are applied in the listed
order (``Zrotation Xrotation Yrotation`` is ``R = Rz Rx Ry``, each about the joint's parent axes
as BVH readers do). Position channels set the joint's position relative to its parent for that
frame (replacing OFFSET, as Blender and most tools read them); only the root's are used.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .axes import guess_metres_per_unit, skeleton_axes
from .clip import MotionClip, MotionFileError, SourceSkeleton, read_motion_bytes
from .rig_clip import first_branch, role_joints, wrapper_note
from .roles import find_roles
from .rotations import euler_to_matrix

CHANNELS = {"xposition": ("P", 0), "yposition": ("P", 1), "zposition": ("P", 2),
            "xrotation": ("R", 0), "yrotation": ("R", 1), "zrotation": ("R", 2)}


class _Tokens:
    def __init__(self, path: str, lines: list[str]) -> None:
        self.path = path
        self.items: list[tuple[int, str]] = []
        for n, line in enumerate(lines, 1):
            for tok in line.replace("{", " { ").replace("}", " } ").split():
                self.items.append((n, tok))
        self.pos = 0
        self.last_line = len(lines)

    def error(self, line: int, msg: str) -> MotionFileError:
        return MotionFileError(f"{self.path}:{line}: {msg}")

    def next(self, what: str) -> tuple[int, str]:
        if self.pos >= len(self.items):
            raise self.error(self.last_line, f"the file ends where {what} was expected (truncated file?)")
        item = self.items[self.pos]
        self.pos += 1
        return item

    def peek(self) -> tuple[int, str] | None:
        return self.items[self.pos] if self.pos < len(self.items) else None

    def expect(self, word: str) -> int:
        line, tok = self.next(repr(word))
        if tok.upper() != word.upper():
            raise self.error(line, f"expected {word!r}, found {tok!r}")
        return line

    def rest_of_line(self, line: int, stop: tuple[str, ...] = ()) -> list[str]:
        out = []
        while (self.pos < len(self.items) and self.items[self.pos][0] == line and self.items[self.pos][1] not in "{}"
               and self.items[self.pos][1].upper() not in stop):
            out.append(self.items[self.pos][1])
            self.pos += 1
        return out

    def number(self, what: str) -> float:
        line, tok = self.next(what)
        try:
            v = float(tok)
        except ValueError:
            raise self.error(line, f"{what}: non-numeric value {tok!r}") from None
        if not np.isfinite(v):
            raise self.error(line, f"{what}: non-finite value {tok!r}")
        return v


class _Joint:
    def __init__(self, name: str, parent: int, line: int) -> None:
        self.name, self.parent, self.line = name, parent, line
        self.offset = np.zeros(3)
        self.channels: list[tuple[str, int]] = []
        self.end_site: np.ndarray | None = None


def _parse_joint(tk: _Tokens, name: str, parent: int, line: int, joints: list[_Joint]) -> None:
    joint = _Joint(name, parent, line)
    index = len(joints)
    joints.append(joint)
    tk.expect("{")
    seen_offset = False
    while True:
        ln, tok = tk.next(f"the end of joint {name!r} (opened at line {line})")
        key = tok.upper()
        if key == "}":
            break
        if key == "OFFSET":
            joint.offset = np.array([tk.number(f"OFFSET of {name!r}") for _ in range(3)])
            seen_offset = True
        elif key == "CHANNELS":
            count_line, count_tok = tk.next(f"the channel count of {name!r}")
            try:
                count = int(count_tok)
            except ValueError:
                raise tk.error(count_line, f"CHANNELS of {name!r}: non-numeric channel count {count_tok!r}") from None
            names = tk.rest_of_line(count_line, ("JOINT", "END", "OFFSET", "CHANNELS"))
            if len(names) != count:
                raise tk.error(count_line, f"CHANNELS of {name!r}: the count says {count} channels, "
                                           f"{len(names)} are listed ({' '.join(names)})")
            for ch in names:
                if ch.lower() not in CHANNELS:
                    raise tk.error(count_line, f"unsupported channel {ch!r} on joint {name!r} "
                                               f"(supported: Xposition Yposition Zposition Xrotation Yrotation Zrotation)")
                joint.channels.append(CHANNELS[ch.lower()])
            rot_axes = [a for kind, a in joint.channels if kind == "R"]
            pos_axes = [a for kind, a in joint.channels if kind == "P"]
            if len(set(rot_axes)) != len(rot_axes) or len(set(pos_axes)) != len(pos_axes):
                raise tk.error(count_line, f"CHANNELS of {name!r} repeat an axis: {' '.join(names)}")
        elif key == "JOINT":
            parts = tk.rest_of_line(ln)
            if not parts:
                raise tk.error(ln, "JOINT without a name")
            _parse_joint(tk, " ".join(parts), index, ln, joints)
        elif key == "END":
            tk.expect("Site")
            tk.expect("{")
            tk.expect("OFFSET")
            joint.end_site = np.array([tk.number(f"End Site OFFSET of {name!r}") for _ in range(3)])
            tk.expect("}")
        else:
            raise tk.error(ln, f"unexpected {tok!r} in joint {name!r} (expected OFFSET, CHANNELS, JOINT, End Site or '}}')")
    if not seen_offset:
        raise tk.error(line, f"joint {name!r} has no OFFSET")


def _header_value(tk: _Tokens, words: list[str]) -> tuple[int, str]:
    """Reads e.g. 'Frames:' N or 'Frame Time:' dt, tolerating 'Frames :' spacing and a value written
    against the colon ('Frames:120', 'Frame Time:0.0333')."""
    first_line = None
    for n, w in enumerate(words):
        ln, tok = tk.next(f"'{' '.join(words)}'")
        first_line = first_line or ln
        if n == len(words) - 1 and w.endswith(":") and tok.lower().startswith(w.lower()) and len(tok) > len(w):
            return ln, tok[len(w):]
        if tok.rstrip(":").lower() != w.rstrip(":").lower():
            raise tk.error(ln, f"expected '{' '.join(words)}', found {tok!r}")
        if not tok.endswith(":") and w.endswith(":"):
            nxt = tk.peek()
            if nxt and nxt[1] == ":":
                tk.next("':'")
    return tk.next(f"the value of '{' '.join(words)}'")


def read_bvh(path: str | os.PathLike, *, up: str | None = None, forward: str | None = None,
             metres_per_unit: float | None = None) -> MotionClip:
    """Reads a BVH file into a ``MotionClip``. ``up``/``forward`` ("+Y", "-Z", ...) override the
    axes detected from the rest skeleton; ``metres_per_unit`` overrides the unit guess."""
    path = Path(path)
    data = read_motion_bytes(path)
    text, decoded = _bvh_text(path, data)
    lines = text.splitlines()
    motion_at = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "MOTION"), None)
    head = lines if motion_at is None else lines[:motion_at]
    tk = _Tokens(str(path), head)
    if not tk.items:
        raise MotionFileError(f"{path}:1: empty file (expected HIERARCHY)")
    tk.expect("HIERARCHY")
    joints: list[_Joint] = []
    ln, tok = tk.next("ROOT")
    if tok.upper() != "ROOT":
        raise tk.error(ln, f"expected ROOT, found {tok!r}")
    name = " ".join(tk.rest_of_line(ln))
    if not name:
        raise tk.error(ln, "ROOT without a name")
    _parse_joint(tk, name, -1, ln, joints)
    extra = tk.peek()
    if extra is not None:
        if extra[1].upper() == "ROOT":
            raise tk.error(extra[0], "a second ROOT: files with several skeletons are not supported")
        raise tk.error(extra[0], f"unexpected {extra[1]!r} after the hierarchy (expected MOTION)")
    if motion_at is None:
        raise MotionFileError(f"{path}:{len(lines)}: no MOTION section (truncated file?)")

    # ----- MOTION ----------------------------------------------------------------------------
    base = motion_at + 1  # 0-based index of the first line after MOTION
    mt = _Tokens(str(path), [""] * base + lines[base:base + 4])
    ln, tok = _header_value(mt, ["Frames:"])
    try:
        num_frames = int(tok)
    except ValueError:
        raise mt.error(ln, f"Frames: non-numeric value {tok!r}") from None
    if num_frames <= 0:
        raise mt.error(ln, f"empty motion: Frames: {num_frames}")
    ln, tok = _header_value(mt, ["Frame", "Time:"])
    try:
        frame_time = float(tok)
    except ValueError:
        raise mt.error(ln, f"Frame Time: non-numeric value {tok!r}") from None
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise mt.error(ln, f"Frame Time must be positive, found {tok!r}")
    data_start = ln  # 1-based line of 'Frame Time'; frames follow
    num_channels = sum(len(j.channels) for j in joints)
    values = np.empty((num_frames, num_channels))
    k = 0
    last_line = data_start
    for i in range(data_start, len(lines)):
        raw = lines[i].split()
        if not raw:
            continue
        if k == num_frames:
            raise MotionFileError(f"{path}:{i + 1}: more frames than 'Frames: {num_frames}' says")
        if len(raw) < num_channels and not any(ln.strip() for ln in lines[i + 1:]):
            raise MotionFileError(f"{path}:{i + 1}: truncated: frame {k} has {len(raw)} of {num_channels} values "
                                  f"and the file ends there ('Frames: {num_frames}')")
        if len(raw) != num_channels:
            raise MotionFileError(f"{path}:{i + 1}: frame {k} has {len(raw)} values, the hierarchy has "
                                  f"{num_channels} channels")
        try:
            row = np.array(raw, dtype=np.float64)
        except ValueError:
            bad = next(t for t in raw if not _is_float(t))
            raise MotionFileError(f"{path}:{i + 1}: frame {k}: non-numeric value {bad!r}") from None
        if not np.all(np.isfinite(row)):
            raise MotionFileError(f"{path}:{i + 1}: frame {k}: non-finite value")
        values[k] = row
        k += 1
        last_line = i + 1
    if k < num_frames:
        raise MotionFileError(f"{path}:{last_line}: truncated: 'Frames: {num_frames}' but the file ends after "
                              f"{k} frames")

    # ----- to arrays ---------------------------------------------------------------------------
    J = len(joints)
    offsets = np.stack([j.offset for j in joints])
    local = np.broadcast_to(np.eye(3), (num_frames, J, 3, 3)).copy()
    pos = np.broadcast_to(offsets, (num_frames, J, 3)).copy()  # each joint's position in its parent
    moves = np.zeros(J, bool)
    notes = []
    col = 0
    for ji, j in enumerate(joints):
        rot_cols, order = [], ""
        for kind, axis in j.channels:
            if kind == "R":
                rot_cols.append(col)
                order += "XYZ"[axis]
            else:
                pos[:, ji, axis] = values[:, col]
                moves[ji] |= np.ptp(values[:, col]) > 1e-6 or abs(values[0, col] - j.offset[axis]) > 1e-6
            col += 1
        if rot_cols:
            local[:, ji] = euler_to_matrix(values[:, rot_cols], order)
    top, wrappers = first_branch(0, lambda i: [c for c, jc in enumerate(joints) if jc.parent == i],
                                 role_joints(list(range(J)), [j.name for j in joints]))
    if wrappers:  # an armature or root bone above the hips: its motion goes into the hips'
        R, p = local[:, 0], pos[:, 0]
        for i in wrappers[1:] + [top]:
            p = p + np.einsum("tij,tj->ti", R, pos[:, i])
            R = R @ local[:, i]
        keep = [i for i in range(J) if i not in wrappers]
        index = {old: new for new, old in enumerate(keep)}
        rest_top = offsets[wrappers].sum(0) + offsets[top]
        notes.append(wrapper_note([joints[i].name for i in wrappers], joints[top].name))
        for i in keep[1:]:
            joints[i].parent = index[joints[i].parent]
        joints = [joints[i] for i in keep]
        joints[0].parent = -1
        offsets = np.concatenate([rest_top[None], offsets[keep[1:]]])
        local = np.concatenate([R[:, None], local[:, keep[1:]]], 1)
        pos = np.concatenate([p[:, None], pos[:, keep[1:]]], 1)
        moves = moves[keep]
    root = pos[:, 0]
    moving_joints = [j.name for j, m in zip(joints[1:], moves[1:]) if m]
    if moving_joints:
        notes.append(f"position channels of {len(set(moving_joints))} non-root joints ignored "
                     f"({', '.join(sorted(set(moving_joints))[:6])}...): bone lengths are the avatar's")
    names = tuple(j.name for j in joints)
    parents = np.array([j.parent for j in joints])
    end_sites = {i: j.end_site for i, j in enumerate(joints) if j.end_site is not None}
    skeleton = SourceSkeleton(names, parents, offsets, end_sites, naming="bvh")
    rest = skeleton.rest_positions()
    up_v, fwd_v, how, C = skeleton_axes(path, names, rest, up, forward)
    unit = metres_per_unit or guess_metres_per_unit(rest, find_roles(names, "bvh"), up_v)
    if decoded != "utf-8":
        notes.append(f"the file is not UTF-8: read as {decoded} (joint names with other characters may "
                     "show wrongly)")
    notes.append(f"axes {how}: up {_axis_name(up_v)}, facing {_axis_name(fwd_v)}; units guessed as "
                 f"{_unit_name(unit)}" if metres_per_unit is None else f"units given: {unit} m per unit")
    return MotionClip(skeleton, local, root, 1.0 / frame_time, C, C, float(unit), str(path), "bvh", tuple(notes))


def _bvh_text(path: Path, data: bytes) -> tuple[str, str]:
    """(text, encoding) of a BVH file's bytes: UTF-8, its byte-order mark dropped (Windows tools
    write one); else Latin-1 (older exporters write joint names in a code page; the format's own
    words are ASCII, so the file still reads). Bytes with NULs are not a text file."""
    if b"\x00" in data[:4096]:
        raise MotionFileError(f"{path}: not a text file (BVH files are text; found binary data, "
                              f"starting {data[:16]!r})")
    try:
        return data.decode("utf-8-sig"), "utf-8"
    except UnicodeDecodeError:
        return data.decode("latin-1"), "Latin-1"


def _is_float(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


def _axis_name(v: np.ndarray) -> str:
    k = int(np.argmax(np.abs(v)))
    return ("+" if v[k] > 0 else "-") + "XYZ"[k]


def _unit_name(u: float) -> str:
    return {1.0: "metres", 0.01: "centimetres", 0.001: "millimetres", 0.0254: "inches"}.get(u, f"{u} m")
