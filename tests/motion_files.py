"""Motion files for the export and studio tests: a BVH written by an independent library (bvhio) and
an SMPL-layout .npz (AMASS keys), both with known motion."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

# A CMU/Mixamo-like skeleton in centimetres, Y up, facing +Z (+X is the body's left), in T-pose.
SKELETON = [
    ("Hips", None, (0.0, 95.0, 0.0)),
    ("LeftUpLeg", "Hips", (9.0, -5.0, 0.0)), ("LeftLeg", "LeftUpLeg", (0.0, -43.0, 0.0)),
    ("LeftFoot", "LeftLeg", (0.0, -42.0, 0.0)), ("LeftToeBase", "LeftFoot", (0.0, -7.0, 13.0)),
    ("RightUpLeg", "Hips", (-9.0, -5.0, 0.0)), ("RightLeg", "RightUpLeg", (0.0, -43.0, 0.0)),
    ("RightFoot", "RightLeg", (0.0, -42.0, 0.0)), ("RightToeBase", "RightFoot", (0.0, -7.0, 13.0)),
    ("Spine", "Hips", (0.0, 10.0, 0.0)), ("Spine1", "Spine", (0.0, 15.0, 0.0)),
    ("Neck", "Spine1", (0.0, 25.0, 0.0)), ("Head", "Neck", (0.0, 10.0, 2.0)),
    ("LeftShoulder", "Spine1", (3.0, 20.0, 0.0)), ("LeftArm", "LeftShoulder", (15.0, 0.0, 0.0)),
    ("LeftForeArm", "LeftArm", (28.0, 0.0, 0.0)), ("LeftHand", "LeftForeArm", (25.0, 0.0, 0.0)),
    ("RightShoulder", "Spine1", (-3.0, 20.0, 0.0)), ("RightArm", "RightShoulder", (-15.0, 0.0, 0.0)),
    ("RightForeArm", "RightArm", (-28.0, 0.0, 0.0)), ("RightHand", "RightForeArm", (-25.0, 0.0, 0.0)),
    ("LeftHandIndex1", "LeftHand", (5.0, 0.0, 0.0)),  # a finger: no bone on the avatar (dropped, with a note)
]
END_SITES = {"LeftToeBase": (0.0, 0.0, 5.0), "RightToeBase": (0.0, 0.0, 5.0), "Head": (0.0, 18.0, 0.0),
             "LeftHandIndex1": (3.0, 0.0, 0.0), "RightHand": (-10.0, 0.0, 0.0)}


def _bvhio():
    with warnings.catch_warnings():  # bvhio imports PyGLM under its old name
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import bvhio
        import glm
    return bvhio, glm


def arm_swing_angles(frames: int) -> np.ndarray:
    """Degrees the arms are lowered from the T-pose in each frame: 0 (T-pose) to 80 and back."""
    return 80.0 * np.sin(np.linspace(0.0, math.pi, frames))


def write_test_bvh(path, frames: int = 40, fps: float = 30.0) -> Path:
    """A BVH (written with bvhio): the arms go down from a T-pose and back up, the legs swing, the
    hips walk forward 1 cm a frame (+Z, the file's facing)."""
    bvhio, glm = _bvhio()
    angles = arm_swing_angles(frames)
    legs = 25.0 * np.sin(np.linspace(0.0, 2 * math.pi, frames))

    def q(axis, deg):
        return glm.angleAxis(math.radians(float(deg)), glm.normalize(glm.vec3(*axis)))

    rotations = {
        "LeftArm": [q((0, 0, 1), -a) for a in angles],  # +X arm turned down about +Z
        "RightArm": [q((0, 0, 1), a) for a in angles],
        "LeftUpLeg": [q((1, 0, 0), -b) for b in legs],
        "RightUpLeg": [q((1, 0, 0), b) for b in legs],
    }
    joints = {}
    for name, parent, offset in SKELETON:
        j = bvhio.BvhJoint(name, glm.vec3(*offset))
        j.Channels = (["Xposition", "Yposition", "Zposition"] if parent is None else []) + \
            ["Zrotation", "Xrotation", "Yrotation"]
        if name in END_SITES:
            j.EndSite = glm.vec3(*END_SITES[name])
        qs = rotations.get(name, [glm.quat()] * frames)
        pos = [glm.vec3(0.0, 95.0, float(f)) for f in range(frames)] if parent is None else [glm.vec3(*offset)] * frames
        j.Keyframes = [bvhio.Pose(pos[f], qs[f]) for f in range(frames)]
        joints[name] = j
        if parent is not None:
            joints[parent].Children.append(j)
    bvhio.writeBvh(str(path), bvhio.BvhContainer(joints["Hips"], frames, 1.0 / fps), percision=6)
    return Path(path)


def write_test_npz(path, frames: int = 30, fps: float = 60.0) -> Path:
    """An SMPL-layout sequence (AMASS keys: poses (T,72) axis-angle, trans (T,3), mocap_framerate):
    the left elbow bends to 90 degrees, the right shoulder lifts; Z-up world, 1 m/s along +Y."""
    t = np.linspace(0.0, 1.0, frames)
    poses = np.zeros((frames, 72))
    poses[:, 0] = math.pi / 2  # AMASS: root turned from SMPL's Y-up rest to the Z-up world
    poses[:, 18 * 3 + 1] = -math.radians(90.0) * t  # left elbow (joint 18) about Y
    poses[:, 17 * 3 + 2] = math.radians(60.0) * t  # right shoulder (joint 17) about Z
    trans = np.stack([np.zeros(frames), t * frames / fps, np.full(frames, 0.95)], 1)
    np.savez(path, poses=poses, trans=trans, mocap_framerate=np.float64(fps), betas=np.zeros(10))
    return Path(path)
