"""Joint roles: which bone of a skeleton plays which part (hips, left upper arm, ...).

The table extends the role idea of ``reconstruct/body/novel_poses.py`` to motion files. Each role
lists candidate names per naming scheme: the avatar bodies (Anny, the SMPL backend's labels), SMPL
joint names (SMPL / SMPL-H / SMPL-X sequences) and common BVH skeletons (CMU, Mixamo, MotionBuilder
and similar). BVH names are compared after normalising: the namespace before ``:`` is dropped
(``mixamorig:LeftArm``), and case, spaces, ``_``, ``-`` and ``.`` are ignored; a prefix that every
joint shares is dropped (``without_rig_prefix``: ``Bip01 L Thigh``, ``Character1_Hips``), and a side
may come first or last (``LeftArm``, ``upperarm_l``, ``thigh.L``).

The spine between the hips and the neck is matched by position, not by name: skeletons have 1 to 5
spine joints, so each source spine joint goes to the avatar spine bone at the nearest fraction of
the hips-to-neck length (each used once).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

SIDES = {"l": ("Left", "L", "l"), "r": ("Right", "R", "r")}


def _side_last(template: str) -> str | None:
    """The template with its leading side token moved to the end ("{Side}Arm" -> "Arm{Side}",
    "{S}_Thigh" -> "Thigh_{S}"), or None when it does not start with one."""
    m = re.match(r"(\{Side\}|\{S\}|\{s\})(_?)(.+)$", template)
    return None if m is None else f"{m.group(3)}{m.group(2)}{m.group(1)}"


def _sided(role: str, anny: str, smpl_body: str, smpl: str, bvh: tuple[str, ...]) -> dict:
    # every name with its side first also with its side last (Unreal's thigh_l, Blender's thigh.L)
    bvh = bvh + tuple(t for t in map(_side_last, bvh) if t is not None and t not in bvh)
    out = {}
    for s, (word, letter, low) in SIDES.items():
        names = tuple(n.format(Side=word, S=letter, s=low) for n in bvh)
        out[f"{role}_{s}"] = {
            "anny": (anny.format(S=letter),),
            "smpl_body": (smpl_body.format(S=letter),),
            "smpl": (smpl.format(side=word.lower()),),
            "bvh": names,
        }
    return out


# role -> naming -> candidate names (first match wins)
ROLE_TABLE: dict[str, dict[str, tuple[str, ...]]] = {
    "hips": {"anny": ("root",), "smpl_body": ("pelvis",), "smpl": ("pelvis",),
             "bvh": ("Hips", "Hip", "Pelvis", "Root", "hip")},
    "neck": {"anny": ("neck01",), "smpl_body": ("neck",), "smpl": ("neck",),
             "bvh": ("Neck", "Neck0", "Neck1", "Neck01", "LowerNeck")},
    "head": {"anny": ("head",), "smpl_body": ("head",), "smpl": ("head",), "bvh": ("Head",)},
    **_sided("clavicle", "clavicle.{S}", "clavicle.{S}", "{side}_collar",
             ("{Side}Shoulder", "{Side}Collar", "{Side}Clavicle", "{s}clavicle", "{S}Collar", "{S}_Clavicle", "Shoulder_{S}", "Clavicle_{S}")),
    **_sided("upperarm", "upperarm01.{S}", "upperarm.{S}", "{side}_shoulder",
             ("{Side}Arm", "{Side}UpArm", "{Side}UpperArm", "{s}humerus", "{S}UpperArm", "{S}_Upperarm", "UpperArm_{S}")),
    **_sided("lowerarm", "lowerarm01.{S}", "lowerarm.{S}", "{side}_elbow",
             ("{Side}ForeArm", "{Side}LowerArm", "{Side}Elbow", "{s}radius", "{S}Forearm", "{S}_Forearm", "{S}Elbow", "LowerArm_{S}")),
    **_sided("hand", "wrist.{S}", "wrist.{S}", "{side}_wrist",
             ("{Side}Hand", "{Side}Wrist", "{s}hand", "{S}Hand", "{S}_Hand", "{S}Wrist", "Hand_{S}")),
    **_sided("upperleg", "upperleg01.{S}", "upperleg.{S}", "{side}_hip",
             ("{Side}UpLeg", "{Side}UpperLeg", "{Side}Thigh", "{Side}Hip", "{s}femur", "{S}Thigh", "{S}_Thigh", "{S}Hip", "UpperLeg_{S}")),
    **_sided("lowerleg", "lowerleg01.{S}", "lowerleg.{S}", "{side}_knee",
             ("{Side}Leg", "{Side}LowLeg", "{Side}LowerLeg", "{Side}Knee", "{Side}Shin", "{s}tibia", "{S}Knee",
              "{S}_Calf", "{S}Calf", "{S}Shin", "LowerLeg_{S}")),
    **_sided("foot", "foot.{S}", "foot.{S}", "{side}_ankle",
             ("{Side}Foot", "{Side}Ankle", "{s}foot", "{S}Foot", "{S}_Foot", "{S}Ankle", "Foot_{S}")),
    **_sided("toe", "", "toe.{S}", "{side}_foot",
             ("{Side}ToeBase", "{Side}Toe", "{Side}Toes", "{s}toes", "{S}Toe", "{S}_Toe0", "{S}Toes", "Toes_{S}",
              "{S}Ball")),
}

# The bone each role points at (its "tip"): a bone's rest direction is head -> the tip role's head.
TIP_ROLE = {"neck": "head"}
for _s in ("l", "r"):
    TIP_ROLE.update({f"clavicle_{_s}": f"upperarm_{_s}", f"upperarm_{_s}": f"lowerarm_{_s}",
                     f"lowerarm_{_s}": f"hand_{_s}", f"upperleg_{_s}": f"lowerleg_{_s}",
                     f"lowerleg_{_s}": f"foot_{_s}", f"foot_{_s}": f"toe_{_s}"})
# Roles whose rest direction is not compared (no reliable tip): they take their parent's alignment.
INHERIT_ALIGNMENT = {"hips", "head", "hand_l", "hand_r", "toe_l", "toe_r"}


def normalise(name: str) -> str:
    name = name.split(":")[-1]
    name = name.split("|")[-1]
    return re.sub(r"[\s_\-.]", "", name).lower()


def without_rig_prefix(names: list[str]) -> list[str]:
    """Normalised joint names with a prefix that every joint but the first shares dropped (3ds Max
    Biped's "Bip01 L Thigh", HumanIK's "Character1_LeftUpLeg", Rigify's "DEF-thigh.L"): the first
    joint (the root) may be the prefix alone ("Bip01") and keeps its name then. Unchanged with
    fewer than 4 joints, for a prefix under 3 letters or one that starts with a side ("left..."),
    or when dropping the prefix would leave a name empty."""
    rest = names[1:]
    if len(names) < 4:
        return list(names)
    prefix = os.path.commonprefix(rest)
    if len(prefix) < 3 or prefix.startswith(("left", "right")) or any(len(n) == len(prefix) for n in rest):
        return list(names)
    first = names[0][len(prefix):] if names[0].startswith(prefix) and len(names[0]) > len(prefix) else names[0]
    return [first] + [n[len(prefix):] for n in rest]


def find_roles(names: list[str] | tuple[str, ...], naming: str) -> dict[str, int]:
    """role -> joint index for the joints of a skeleton named in ``naming`` ("anny", "smpl_body",
    "smpl" or "bvh"). BVH names are compared normalised."""
    if naming == "bvh":
        index = {}
        for i, n in enumerate(without_rig_prefix([normalise(n) for n in names])):
            index.setdefault(n, i)
        key = normalise
    else:
        index = {n: i for i, n in enumerate(names)}

        def key(n):
            return n
    out: dict[str, int] = {}
    used: set[int] = set()
    for role, table in ROLE_TABLE.items():
        for cand in table.get(naming, ()):
            if not cand:
                continue
            i = index.get(key(cand))
            if i is not None and i not in used:
                out[role] = i
                used.add(i)
                break
    return out


def body_naming(labels: list[str]) -> str:
    """Which naming scheme a body's bone labels follow."""
    if "upperleg01.L" in labels:
        return "anny"
    if "upperleg.L" in labels and "pelvis" in labels:
        return "smpl_body"
    return "bvh"


def _path(parents: np.ndarray, start: int, end: int) -> list[int] | None:
    """Joint indices strictly between ``start`` and its descendant ``end`` (top down), or None."""
    chain, j = [], int(parents[end])
    while j >= 0 and j != start:
        chain.append(j)
        j = int(parents[j])
    return chain[::-1] if j == start else None


def spine_chain(parents: np.ndarray, positions: np.ndarray, roles: dict[str, int]) -> tuple[list[int], np.ndarray]:
    """The spine joints between the hips and the neck (or head) and their fraction (0..1) of the
    hips-to-neck height; joints at the hips' own position count as fraction 0."""
    top = roles.get("neck", roles.get("head"))
    if "hips" not in roles or top is None:
        return [], np.zeros(0)
    chain = _path(parents, roles["hips"], top)
    if not chain:
        return [], np.zeros(0)
    a, b = positions[roles["hips"]], positions[top]
    axis = b - a
    L2 = float(axis @ axis)
    if L2 < 1e-12:
        return [], np.zeros(0)
    frac = np.array([float((positions[j] - a) @ axis) / L2 for j in chain])
    return chain, frac


@dataclass(frozen=True)
class BoneMatch:
    """A source joint driving an avatar bone."""

    role: str
    source_joint: int
    body_bone: int


def match_spines(src_chain: list[int], src_frac: np.ndarray, body_chain: list[int], body_frac: np.ndarray
                 ) -> list[tuple[int, int, int]]:
    """Greedy one-to-one matching by nearest fraction: (k, source joint, body bone) sorted by k."""
    pairs = sorted(((abs(float(fs) - float(fb)), i, k) for i, fs in enumerate(src_frac) for k, fb in enumerate(body_frac)))
    used_s, used_b, out = set(), set(), []
    for _, i, k in pairs:
        if i in used_s or k in used_b:
            continue
        used_s.add(i)
        used_b.add(k)
        out.append((i, src_chain[i], body_chain[k]))
    # keep the order along the chain monotonic: drop crossings (a later source joint on a lower bone)
    out.sort()
    kept, last = [], -1
    for i, s, b in out:
        pos = body_chain.index(b)
        if pos > last:
            kept.append((i, s, b))
            last = pos
    return kept
