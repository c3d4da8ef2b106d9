"""Body-part labels shared by the UV maps, the synthetic clothing and the built-in prior."""

from __future__ import annotations

PART_NAMES: tuple[str, ...] = (
    "torso", "head", "neck",
    "upperarm.L", "lowerarm.L", "hand.L",
    "upperarm.R", "lowerarm.R", "hand.R",
    "thigh.L", "shin.L", "foot.L",
    "thigh.R", "shin.R", "foot.R",
)
PART_INDEX = {name: i for i, name in enumerate(PART_NAMES)}

# Mirror partner of each part (front/back correspondence uses the same part; left/right mirrors).
MIRROR = {n: (n[:-1] + ("R" if n.endswith("L") else "L")) if n[-2:] in (".L", ".R") else n for n in PART_NAMES}


def part_of_bone(label: str) -> str:
    """Map a skeleton bone label (Anny/MakeHuman or SMPL names) to a body part."""
    side = label[-2:] if label[-2:] in (".L", ".R") else ""
    base = label[: -2] if side else label
    if base.startswith(("upperleg", "pelvis")) and side:
        return "thigh" + side if base.startswith("upperleg") else "torso"
    if base.startswith("lowerleg"):
        return "shin" + side
    if base.startswith(("foot", "toe")):
        return "foot" + side
    if base.startswith(("upperarm", "shoulder")):
        return "upperarm" + side
    if base.startswith("lowerarm"):
        return "lowerarm" + side
    if base.startswith(("wrist", "finger", "metacarpal", "thumb", "index", "middle", "ring", "pinky")):
        return "hand" + side
    if base.startswith("neck"):
        return "neck"
    if base.startswith(("head", "eye", "jaw", "tongue")):
        return "head"
    return "torso"  # root, spine, clavicle, pelvis


# bones too small for an image to pin: fingers, toes, the eyes, the jaw. A per-frame pose correction
# left free on them spins them (on four photos: an eye by 135-160 degrees, toes by 40-90) where a
# few pixels move, and the avatar then wears that twist in every other pose
SMALL_BONE_PREFIXES = ("toe", "finger", "metacarpal", "thumb", "index", "middle", "ring", "pinky", "eye", "jaw",
                       "tongue")


def refinable_bone(label: str) -> bool:
    """Whether per-frame pose refinement may turn this bone (Anny/MakeHuman or SMPL labels): the
    skeleton's limbs, spine, neck and head, not ``SMALL_BONE_PREFIXES``."""
    base = label[:-2] if label[-2:] in (".L", ".R") else label
    return not base.lower().startswith(SMALL_BONE_PREFIXES)
