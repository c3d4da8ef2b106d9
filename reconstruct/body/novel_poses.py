"""Short novel pose sequences for animating a trained avatar: a walk cycle and raising the arms.

Poses follow ``BodyPose``'s convention (axis-angle per bone about its head, in world-aligned axes;
Z up, the body faces -Y; a negative rotation about +X swings a limb forward, as in
``reconstruct.data.synthetic.motion``). Bones are found by role so that Anny and SMPL skeletons
both work; the arm angles are computed from the body's rest skeleton, so "arms up" lifts the arms
from an A-pose (Anny) or a T-pose (SMPL) alike.
"""

from __future__ import annotations

import math

import numpy as np

from .pose import BodyPose

NOVEL_POSES = ("walk", "arms_up")

# role -> candidate bone labels (Anny first, then SMPL)
_ROLES = {
    "hip_l": ("upperleg01.L", "left_hip"),
    "hip_r": ("upperleg01.R", "right_hip"),
    "knee_l": ("lowerleg01.L", "left_knee"),
    "knee_r": ("lowerleg01.R", "right_knee"),
    "shoulder_l": ("upperarm01.L", "left_shoulder"),
    "shoulder_r": ("upperarm01.R", "right_shoulder"),
    "elbow_l": ("lowerarm01.L", "left_elbow"),
    "elbow_r": ("lowerarm01.R", "right_elbow"),
    "chest": ("spine03", "spine3"),
}


def _bones(body) -> dict[str, int]:
    labels = list(body.bone_labels)
    out = {}
    for role, names in _ROLES.items():
        for name in names:
            if name in labels:
                out[role] = labels.index(name)
                break
        else:
            raise ValueError(f"novel poses: body {getattr(body, 'name', '?')} has no bone for {role} "
                             f"(looked for {', '.join(names)})")
    return out


def _base(body, base: BodyPose | None) -> BodyPose:
    """Global orientation and translation of ``base`` (e.g. the video's first frame) with the
    joints at rest, so the novel motion happens where the training camera looks."""
    J = body.num_joints
    if base is None:
        return BodyPose.zeros(J)
    return BodyPose(np.zeros((J, 3)), base.global_orient.copy(), base.transl.copy())


def walk_cycle(body, num_frames: int = 30, *, base: BodyPose | None = None, hip_deg: float = 30.0,
               knee_deg: float = 55.0, arm_deg: float = 25.0, elbow_deg: float = 20.0) -> list[BodyPose]:
    """One walk cycle in place (left step, right step): legs lift, arms swing against the legs."""
    if num_frames < 2:
        raise ValueError(f"walk cycle needs at least 2 frames, found {num_frames}")
    b = _bones(body)
    start = _base(body, base)
    rad = math.radians
    poses = []
    for i in range(num_frames):
        phi = 2.0 * math.pi * i / num_frames
        lift_l, lift_r = max(0.0, math.sin(phi)), max(0.0, -math.sin(phi))
        rot = start.joint_rotations.copy()
        rot[b["hip_l"], 0] = -rad(hip_deg) * lift_l
        rot[b["hip_r"], 0] = -rad(hip_deg) * lift_r
        rot[b["knee_l"], 0] = rad(knee_deg) * lift_l
        rot[b["knee_r"], 0] = rad(knee_deg) * lift_r
        swing = rad(arm_deg) * math.sin(phi)
        rot[b["shoulder_l"], 0] = swing  # left arm back while the left leg lifts
        rot[b["shoulder_r"], 0] = -swing
        rot[b["elbow_l"], 0] = -rad(elbow_deg)
        rot[b["elbow_r"], 0] = -rad(elbow_deg)
        rot[b["chest"], 2] = 0.25 * swing
        bob = 0.015 * (1.0 - abs(math.cos(phi)))
        poses.append(BodyPose(rot, start.global_orient, start.transl + np.array([0.0, 0.0, bob])))
    return poses


def _arm_elevation(body, shoulder: int, elbow: int) -> float:
    """Angle (rad) of the rest upper arm in the frontal (X, Z) plane, measured from the +X axis
    for the arm on +X and mirrored for the other, so that down is negative and up positive."""
    j = np.asarray(body.rest_joints, np.float64)
    d = j[elbow] - j[shoulder]
    return math.atan2(d[2], abs(d[0]))


def arms_up(body, num_frames: int = 30, *, base: BodyPose | None = None, target_deg: float = 65.0,
            hold: float = 0.3) -> list[BodyPose]:
    """Both arms raised sideways from the rest pose until the upper arms point ``target_deg``
    above the horizontal, over the first ``1 - hold`` of the sequence, then held."""
    if num_frames < 2:
        raise ValueError(f"arms up needs at least 2 frames, found {num_frames}")
    b = _bones(body)
    start = _base(body, base)
    joints = np.asarray(body.rest_joints, np.float64)
    poses = []
    ramp = max(1, int(round((num_frames - 1) * (1.0 - hold))))
    for i in range(num_frames):
        s = min(1.0, i / ramp)
        s = 0.5 - 0.5 * math.cos(math.pi * s)  # ease in and out
        rot = start.joint_rotations.copy()
        for side in ("l", "r"):
            sh, el = b[f"shoulder_{side}"], b[f"elbow_{side}"]
            lift = math.radians(target_deg) - _arm_elevation(body, sh, el)  # > 0: the arm goes up
            x_side = 1.0 if joints[el][0] - joints[sh][0] >= 0 else -1.0
            # about +Y, a rotation by phi turns (x, z) from +X towards -Z: for the arm on +X,
            # lifting is a negative rotation about +Y; mirrored for the arm on -X.
            rot[sh, 1] = -x_side * lift * s
            rot[b[f"elbow_{side}"], 1] = -x_side * math.radians(10.0) * s
        poses.append(BodyPose(rot, start.global_orient, start.transl))
    return poses


def novel_pose_sequence(body, name: str, num_frames: int = 30, *, base: BodyPose | None = None) -> list[BodyPose]:
    """The named sequence (``NOVEL_POSES``)."""
    if name == "walk":
        return walk_cycle(body, num_frames, base=base)
    if name in ("arms_up", "arms-up"):
        return arms_up(body, num_frames, base=base)
    raise ValueError(f"unknown novel pose sequence {name!r}; choose one of {', '.join(NOVEL_POSES)}")
