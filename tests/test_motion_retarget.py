"""Retargeting BVH motion onto the Anny body (reconstruct.motion.retarget): bone directions against
an independent forward kinematics of the file (glm, as written by bvhio), rest-pose differences
(T-pose source, A-pose Anny), translation scale, grounding and placement, resampling, looping."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from test_motion_bvh import SKELETON, TO_BODY, expected_world, glm, quat, write_bvh

from reconstruct.body.pose import BodyPose
from reconstruct.motion import load_motion, retarget
from reconstruct.motion.body_kinematics import BodySkeleton
from reconstruct.motion.retarget import body_skeleton

pytestmark = pytest.mark.skipif(glm is None, reason="bvhio (pip install bvhio) writes the test files")

# (Anny bone, Anny bone at its tip) <- (BVH joint, BVH joint at its tip)
PAIRS = [
    (("upperarm01.L", "lowerarm01.L"), ("LeftArm", "LeftForeArm")),
    (("upperarm01.R", "lowerarm01.R"), ("RightArm", "RightForeArm")),
    (("lowerarm01.L", "wrist.L"), ("LeftForeArm", "LeftHand")),
    (("lowerarm01.R", "wrist.R"), ("RightForeArm", "RightHand")),
    (("clavicle.L", "upperarm01.L"), ("LeftShoulder", "LeftArm")),
    (("upperleg01.L", "lowerleg01.L"), ("LeftUpLeg", "LeftLeg")),
    (("upperleg01.R", "lowerleg01.R"), ("RightUpLeg", "RightLeg")),
    (("lowerleg01.L", "foot.L"), ("LeftLeg", "LeftFoot")),
    (("lowerleg01.R", "foot.R"), ("RightLeg", "RightFoot")),
    (("neck01", "head"), ("Neck", "Head")),
]
TOL_DEG = 1.0  # direction error allowed for mapped bones


def angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(np.clip(c, -1.0, 1.0)))


def anny_dir(body, joints: np.ndarray, a: str, b: str) -> np.ndarray:
    L = body.bone_labels
    return joints[L.index(b)] - joints[L.index(a)]


def bvh_dir(rots, frame: int, a: str, b: str, root=(0.0, 95.0, 0.0)) -> np.ndarray:
    _, wp = expected_world(rots, frame, root)
    return TO_BODY @ (np.array(wp[b].to_list()) - np.array(wp[a].to_list()))


@pytest.fixture(scope="module")
def body(anny_body):
    return anny_body


def test_numpy_kinematics_match_the_body(body):
    sk = BodySkeleton(body)
    rng = np.random.default_rng(1)
    J = body.num_joints
    poses = [BodyPose(rng.normal(0, 0.3, (J, 3)), rng.normal(0, 0.5, 3), rng.normal(0, 1, 3)) for _ in range(2)]
    E, p, G, t = sk.forward_poses(poses)
    for i, pose in enumerate(poses):
        ref = body.posed_joints(pose).numpy()
        np.testing.assert_allclose(p[i] @ G[i].T + t[i], ref, atol=1e-9)
        v = body.posed_vertices(pose).numpy()[sk.foot_vertices]
        assert sk.foot_heights(E[i:i + 1], p[i:i + 1], np.array([0, 0, 1.0]), G[i:i + 1], t[i:i + 1])[0] == \
            pytest.approx(v[:, 2].min(), abs=1e-9)


def test_t_pose_source_puts_anny_arms_out_and_45_down_gives_45_down(body, tmp_path):
    """A T-posed frame makes Anny's (A-posed) arms horizontal; arms 45 degrees down in the file give
    Anny's upper and lower arms 45 degrees down (within TOL_DEG)."""
    rots = {"LeftArm": [glm.quat(), quat((0, 0, 1), -45.0)], "RightArm": [glm.quat(), quat((0, 0, 1), 45.0)]}
    clip = load_motion(write_bvh(tmp_path / "arms.bvh", rots, [(0, 95, 0)] * 2))
    res = retarget(clip, body)
    rest, down = (body.posed_joints(p).numpy() for p in res.poses)
    for side, sign in (("L", 1.0), ("R", -1.0)):
        for a, b in ((f"upperarm01.{side}", f"lowerarm01.{side}"), (f"lowerarm01.{side}", f"wrist.{side}")):
            assert angle_deg(anny_dir(body, rest, a, b), [sign, 0, 0]) < TOL_DEG
            d = anny_dir(body, down, a, b)
            assert angle_deg(d, [sign * math.sqrt(0.5), 0, -math.sqrt(0.5)]) < TOL_DEG
            assert math.degrees(math.asin(d[2] / np.linalg.norm(d))) == pytest.approx(-45.0, abs=TOL_DEG)


def test_random_joint_angles_give_the_files_bone_directions(body, tmp_path):
    rng = np.random.default_rng(7)
    T = 6
    rots = {name: [quat(rng.normal(size=3), rng.uniform(-40, 40)) for _ in range(T)] for name, _, _ in SKELETON}
    roots = [(rng.normal() * 20, 95 + rng.normal() * 3, rng.normal() * 20) for _ in range(T)]
    clip = load_motion(write_bvh(tmp_path / "random.bvh", rots, roots))
    res = retarget(clip, body, keep_heading=True)
    assert res.num_frames == T
    worst = 0.0
    for f in range(T):
        joints = body.posed_joints(res.poses[f]).numpy()
        for (a, b), (sa, sb) in PAIRS:
            worst = max(worst, angle_deg(anny_dir(body, joints, a, b), bvh_dir(rots, f, sa, sb, roots[f])))
        # the feet point at the toes: Anny's foot -> mean of its toes against LeftFoot -> LeftToeBase
        L = body.bone_labels
        toes = [i for i, l in enumerate(L) if l.startswith("toe") and l.endswith("-1.L")]
        d = joints[toes].mean(0) - joints[L.index("foot.L")]
        worst = max(worst, angle_deg(d, bvh_dir(rots, f, "LeftFoot", "LeftToeBase", roots[f])))
    assert worst < TOL_DEG, worst


# the test skeleton's joints as other rigs name them (the spine is matched by position, not name)
RIG_NAMES = {
    "3ds Max Biped": {"Hips": "Bip01 Pelvis", "LeftUpLeg": "Bip01 L Thigh", "LeftLeg": "Bip01 L Calf",
                      "LeftFoot": "Bip01 L Foot", "LeftToeBase": "Bip01 L Toe0", "Spine": "Bip01 Spine",
                      "Spine1": "Bip01 Spine1", "Neck": "Bip01 Neck", "Head": "Bip01 Head",
                      "LeftShoulder": "Bip01 L Clavicle", "LeftArm": "Bip01 L UpperArm",
                      "LeftForeArm": "Bip01 L Forearm", "LeftHand": "Bip01 L Hand"},
    "Unreal": {"Hips": "pelvis", "LeftUpLeg": "thigh_l", "LeftLeg": "calf_l", "LeftFoot": "foot_l",
               "LeftToeBase": "ball_l", "Spine": "spine_01", "Spine1": "spine_02", "Neck": "neck_01", "Head": "head",
               "LeftShoulder": "clavicle_l", "LeftArm": "upperarm_l", "LeftForeArm": "lowerarm_l", "LeftHand": "hand_l"},
    "Blender Rigify": {"Hips": "DEF-hips", "LeftUpLeg": "DEF-thigh.L", "LeftLeg": "DEF-shin.L",
                       "LeftFoot": "DEF-foot.L", "LeftToeBase": "DEF-toe.L", "Spine": "DEF-spine",
                       "Spine1": "DEF-chest", "Neck": "DEF-neck", "Head": "DEF-head",
                       "LeftShoulder": "DEF-shoulder.L", "LeftArm": "DEF-upper_arm.L",
                       "LeftForeArm": "DEF-forearm.L", "LeftHand": "DEF-hand.L"},
    "HumanIK": {n: f"Character1_{n}" for n, _, _ in SKELETON},
}


def _rig_name(rig: str, name: str) -> str:
    names = RIG_NAMES[rig]
    if name in names or not name.startswith("Right"):
        return names.get(name, name)
    left = names["Left" + name[len("Right"):]]  # the right side as the rig writes its left
    for a, b in ((" L ", " R "), ("_l", "_r"), (".L", ".R"), ("Left", "Right")):
        if a in left:
            return left.replace(a, b)
    raise AssertionError(left)


@pytest.mark.parametrize("rig", sorted(RIG_NAMES))
def test_rigs_that_name_their_joints_otherwise_drive_the_same_bones(body, tmp_path, rig):
    """The same motion with the joints named as 3ds Max Biped, Unreal, Blender's Rigify and HumanIK
    name them (a prefix every joint shares, the side last): every bone is found and the poses equal
    the plain file's (before, Biped's, Rigify's and HumanIK's files matched no joint at all, and
    Unreal's matched neither the legs nor the neck)."""
    rng = np.random.default_rng(3)
    T = 3
    rots = {name: [quat(rng.normal(size=3), rng.uniform(-40, 40)) for _ in range(T)] for name, _, _ in SKELETON}
    roots = [(rng.normal() * 20, 95 + rng.normal() * 3, rng.normal() * 20) for _ in range(T)]
    plain_path = write_bvh(tmp_path / "plain.bvh", rots, roots)
    text = plain_path.read_text()
    for name, _, _ in sorted(SKELETON, key=lambda j: -len(j[0])):  # LeftForeArm before LeftArm
        text = re.sub(rf"\b(ROOT|JOINT) {name}\b", rf"\1 {_rig_name(rig, name)}", text)
    renamed = tmp_path / "renamed.bvh"
    renamed.write_text(text)
    plain, other = retarget(load_motion(plain_path), body), retarget(load_motion(renamed), body)
    assert not [n for n in plain.notes + other.notes if "has no joint for" in n], other.notes
    assert len(other.dropped) == len(plain.dropped)
    for a, b in zip(plain.poses, other.poses):
        np.testing.assert_allclose(b.joint_rotations, a.joint_rotations, atol=1e-9)
        np.testing.assert_allclose(b.global_orient, a.global_orient, atol=1e-9)
        np.testing.assert_allclose(b.transl, a.transl, atol=1e-9)


def test_root_translation_scaled_by_leg_length(body, tmp_path):
    T = 11
    roots = [(0.0, 95.0, 10.0 * f) for f in range(T)]  # 1 m forward (+Z in the file) over the clip
    clip = load_motion(write_bvh(tmp_path / "forward.bvh", {}, roots))
    res = retarget(clip, body)
    sk = body_skeleton(body)
    leg_body = sum(np.linalg.norm(sk.zero_heads[body.bone_labels.index(b)] - sk.zero_heads[body.bone_labels.index(a)])
                   for a, b in (("upperleg01.L", "lowerleg01.L"), ("lowerleg01.L", "foot.L")))
    assert res.scale == pytest.approx(leg_body / 85.0, rel=1e-6)  # the file's leg: 43 + 42 cm
    hips = body.bone_labels.index("root")
    first, last = (body.posed_joints(res.poses[i]).numpy()[hips] for i in (0, -1))
    np.testing.assert_allclose(last - first, [0.0, -100.0 * res.scale, 0.0], atol=1e-9)  # forward is -Y


@pytest.fixture(scope="module")
def walk_file(tmp_path_factory) -> tuple[Path, dict]:
    """Two walk cycles at 30 fps in centimetres: legs swing, knees bend, arms swing, moving forward."""
    path = tmp_path_factory.mktemp("walk") / "walk.bvh"
    T, fps = 60, 30.0
    rots: dict[str, list] = {n: [] for n in ("LeftUpLeg", "RightUpLeg", "LeftLeg", "RightLeg", "LeftArm", "RightArm",
                                             "LeftForeArm", "RightForeArm", "Hips")}
    roots = []
    for f in range(T):
        phi = 2 * math.pi * f / 30.0
        s = math.sin(phi)
        rots["LeftUpLeg"].append(quat((1, 0, 0), -25 * s))  # about +X: negative swings the leg forward (+Z)
        rots["RightUpLeg"].append(quat((1, 0, 0), 25 * s))
        rots["LeftLeg"].append(quat((1, 0, 0), 40 * max(0.0, s)))
        rots["RightLeg"].append(quat((1, 0, 0), 40 * max(0.0, -s)))
        rots["LeftArm"].append(quat((0, 0, 1), -70) * quat((0, 1, 0), 0.0) * quat((1, 0, 0), 15 * s))
        rots["RightArm"].append(quat((0, 0, 1), 70) * quat((1, 0, 0), -15 * s))
        rots["LeftForeArm"].append(quat((0, 1, 0), 20))
        rots["RightForeArm"].append(quat((0, 1, 0), -20))
        rots["Hips"].append(quat((0, 1, 0), 30))  # the file's walker heads 30 degrees off +Z
        roots.append((math.sin(math.radians(30)) * 4.0 * f, 95 + 2 * abs(math.cos(phi)), math.cos(math.radians(30)) * 4.0 * f))
    return write_bvh(path, rots, roots, 1 / fps), rots


def test_grounding_and_placement_on_the_scene(small_scene, walk_file):
    """The clip's lowest foot point over all frames lands on the floor of the scene's poses (within
    1 cm), starts at the base pose's hips and faces the way the base pose faces."""
    body = small_scene.body_model()
    floor_poses = [f.pose for f in small_scene.frames]
    base = small_scene.frames[0].pose
    res = retarget(load_motion(walk_file[0]), body, base_pose=base, floor_poses=floor_poses)
    sk = body_skeleton(body)
    foot = sk.foot_vertices
    all_foot = np.nonzero(np.isin(np.asarray(body.vertex_parts), [11, 14]))[0]  # foot.L, foot.R part indices
    assert set(foot) <= set(all_foot)
    floor = min(float(body.posed_vertices(p).numpy()[all_foot, 2].min()) for p in floor_poses)
    lowest = min(float(body.posed_vertices(p).numpy()[all_foot, 2].min()) for p in res.poses)
    assert abs(lowest - floor) < 0.01, (lowest, floor)
    hips = body.bone_labels.index("root")
    start = body.posed_joints(res.poses[0]).numpy()[hips]
    ref = body.posed_joints(base).numpy()[hips]
    np.testing.assert_allclose(start[:2], ref[:2], atol=1e-6)
    from reconstruct.motion.rotations import rotvec_to_matrix

    def facing(pose):
        R = rotvec_to_matrix(pose.global_orient) @ rotvec_to_matrix(pose.joint_rotations[hips])
        f = R @ np.array([0, -1.0, 0])
        return f[:2] / np.linalg.norm(f[:2])

    assert angle_deg(facing(res.poses[0]), facing(base)) < 0.5
    # the walker moves the way it faces: 1.16 m per second of the file's 30-degree heading, now forward
    move = body.posed_joints(res.poses[30]).numpy()[hips] - start
    assert angle_deg(move[:2], facing(base)) < 2.0


def test_resampling_trimming_and_loop(body, tmp_path):
    T, fps = 31, 30.0
    rots = {"LeftArm": [quat((0, 0, 1), -3.0 * f) for f in range(T)]}  # 90 degrees per second
    clip = load_motion(write_bvh(tmp_path / "ramp.bvh", rots, [(0, 95, 0)] * T, 1 / fps))
    res = retarget(clip, body, fps=60, start=0.25, end=0.75)
    assert res.fps == 60 and res.num_frames == 31
    for k in (0, 7, 30):  # 7: between two file frames, slerped
        t = 0.25 + k / 60
        joints = body.posed_joints(res.poses[k]).numpy()
        d = anny_dir(body, joints, "upperarm01.L", "lowerarm01.L")
        elev = math.degrees(math.atan2(d[2], d[0]))
        assert elev == pytest.approx(-90.0 * t, abs=0.2)
    res10 = retarget(clip, body, fps=10)
    assert res10.num_frames == 11
    with pytest.raises(ValueError, match="start 2 s is outside the clip"):
        retarget(clip, body, start=2.0)


def test_loop_joins_end_to_start(body, walk_file):
    res = retarget(load_motion(walk_file[0]), body, loop=True, start=0.0, end=1.0)
    assert res.num_frames == 30  # the frame at 1 s would repeat the first
    first, last = res.poses[0], res.poses[-1]
    # one frame before the seam: close to the first frame (one frame of motion)
    assert np.abs(first.joint_rotations - last.joint_rotations).max() < math.radians(12)
    hips = body.bone_labels.index("root")
    drift = body.posed_joints(last).numpy()[hips] - body.posed_joints(first).numpy()[hips]
    assert np.linalg.norm(drift[:2]) < 0.05  # in place (the file walks 1.2 m per second)
    assert any("looped" in n for n in res.notes)


def test_missing_and_extra_joints_are_noted(body, tmp_path):
    text = """HIERARCHY
ROOT Hips
{
  OFFSET 0 95 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT LeftUpLeg { OFFSET 9 -5 0 CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT LeftLeg { OFFSET 0 -43 0 CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT LeftFoot { OFFSET 0 -42 0 CHANNELS 3 Zrotation Xrotation Yrotation End Site { OFFSET 0 -5 12 } } } }
  JOINT RightUpLeg { OFFSET -9 -5 0 CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT RightLeg { OFFSET 0 -43 0 CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT RightFoot { OFFSET 0 -42 0 CHANNELS 3 Zrotation Xrotation Yrotation End Site { OFFSET 0 -5 12 } } } }
  JOINT Chest { OFFSET 0 30 0 CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Head { OFFSET 0 30 0 CHANNELS 3 Zrotation Xrotation Yrotation End Site { OFFSET 0 15 0 } }
    JOINT Tail { OFFSET 0 -30 -10 CHANNELS 3 Zrotation Xrotation Yrotation End Site { OFFSET 0 -20 -10 } } }
}
MOTION
Frames: 1
Frame Time: 0.04
0 95 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 30 0 0 0 0 0 0 0 0
"""
    path = tmp_path / "partial.bvh"
    path.write_text(text)
    res = retarget(load_motion(path), body)
    assert "Tail" in res.dropped
    notes = " | ".join(res.notes)
    assert "Tail" in notes and "upperarm_l" in notes  # no arms in the file: they stay at rest
    L = body.bone_labels
    for bone in ("clavicle.L", "upperarm01.L", "lowerarm01.R"):
        np.testing.assert_allclose(res.poses[0].joint_rotations[L.index(bone)], 0.0, atol=1e-9)


def test_scene_world_that_is_not_z_up(body, walk_file):
    """A base pose in a Y-down world (camera-like axes, as some dataset SMPL fits): the clip stands
    along that world's up, starts at the base's hips, and its lowest foot point lands on the base's."""
    from reconstruct.motion.rotations import rotvec_to_matrix

    R = rotvec_to_matrix(np.array([math.pi / 2, 0.0, 0.0]))  # the body's +Z becomes the world's -Y
    base = BodyPose(np.zeros((body.num_joints, 3)), np.array([math.pi / 2, 0.0, 0.0]), np.array([0.3, 1.0, 4.0]))
    res = retarget(load_motion(walk_file[0]), body, base_pose=base)
    up = R @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(res.up, up, atol=1e-9)
    L = body.bone_labels
    for pose in res.poses[::10]:
        j = body.posed_joints(pose).numpy()
        assert angle_deg(j[L.index("neck01")] - j[L.index("root")], up) < 15.0
    sk = body_skeleton(body)
    v0 = body.posed_vertices(base).numpy()[sk.foot_vertices] @ up
    lows = [float((body.posed_vertices(p).numpy()[sk.foot_vertices] @ up).min()) for p in res.poses]
    assert min(lows) == pytest.approx(v0.min(), abs=1e-6)
    start = body.posed_joints(res.poses[0]).numpy()[L.index("root")]
    ref = body.posed_joints(base).numpy()[L.index("root")]
    horiz = np.eye(3) - np.outer(up, up)
    np.testing.assert_allclose(horiz @ start, horiz @ ref, atol=1e-6)
