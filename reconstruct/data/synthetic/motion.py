"""Walking in place while turning: the synthetic scenes' motion (joint angles within human limits)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...body.pose import BodyPose


@dataclass(frozen=True)
class MotionConfig:
    step_period_s: float = 1.1  # one left+right step
    hip_flexion_deg: float = 28.0  # lifted leg (human limit ~120)
    knee_flexion_deg: float = 50.0  # lifted leg (human limit ~140)
    arm_swing_deg: float = 22.0  # shoulder flexion/extension (limits ~180 / ~50)
    elbow_flexion_deg: float = 20.0  # mean elbow bend (limit ~145)
    max_turn_deg: float = 35.0  # turning within +-35 deg of frontal
    bob_m: float = 0.012  # vertical bob of the body


# (bone label, axis, sign): the joints the motion drives. Rotations are about world-aligned axes
# at each bone's head; the body faces -Y, so a negative rotation about +X swings a limb forward.
def walk_in_place(labels: list[str], num_frames: int, fps: float, rng: np.random.Generator,
                  config: MotionConfig = MotionConfig()) -> list[BodyPose]:
    """Per-frame poses: marching in place with arm swing while turning left and right."""
    J = len(labels)
    idx = {name: labels.index(name) for name in labels}
    duration = num_frames / fps
    turn_amp = math.radians(rng.uniform(0.75, 1.0) * config.max_turn_deg)
    turn_phase = rng.uniform(0, 2 * math.pi)
    step_phase = rng.uniform(0, 2 * math.pi)
    head_amp = math.radians(rng.uniform(5, 12))
    rad = math.radians
    poses = []
    for i in range(num_frames):
        t = i / fps
        phi = 2 * math.pi * t / config.step_period_s + step_phase
        lift_l, lift_r = max(0.0, math.sin(phi)), max(0.0, -math.sin(phi))
        rot = np.zeros((J, 3))
        rot[idx["upperleg01.L"], 0] = -rad(config.hip_flexion_deg) * lift_l
        rot[idx["upperleg01.R"], 0] = -rad(config.hip_flexion_deg) * lift_r
        rot[idx["lowerleg01.L"], 0] = rad(config.knee_flexion_deg) * lift_l
        rot[idx["lowerleg01.R"], 0] = rad(config.knee_flexion_deg) * lift_r
        swing = rad(config.arm_swing_deg) * math.sin(phi)
        rot[idx["upperarm01.L"], 0] = swing  # left arm back while the left leg lifts
        rot[idx["upperarm01.R"], 0] = -swing
        rot[idx["lowerarm01.L"], 0] = -rad(config.elbow_flexion_deg) * (1.0 + 0.3 * math.sin(phi))
        rot[idx["lowerarm01.R"], 0] = -rad(config.elbow_flexion_deg) * (1.0 - 0.3 * math.sin(phi))
        rot[idx["spine03"], 2] = 0.25 * swing  # counter-rotation of the chest
        rot[idx["head"], 2] = head_amp * math.sin(2 * math.pi * t / max(duration, 1e-6) * 1.5)
        turn = turn_amp * math.sin(2 * math.pi * t / max(duration, 1e-6) + turn_phase)
        bob = config.bob_m * (1.0 - abs(math.cos(phi)))
        poses.append(BodyPose(rot, np.array([0.0, 0.0, turn]), np.array([0.0, 0.0, bob])))
    return poses
