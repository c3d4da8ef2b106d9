"""Novel pose sequences (walk cycle, arms up) for animating a trained avatar."""

from __future__ import annotations

import numpy as np
import pytest


def _posed_joint(body, pose, label):
    j = body.bone_labels.index(label)
    T = body.bone_transforms(pose).numpy()
    return (T[j] @ np.append(body.rest_joints[j].numpy(), 1.0))[:3]


def test_arms_up_raises_both_elbows_above_the_shoulders(anny_body):
    from reconstruct.body.novel_poses import novel_pose_sequence

    poses = novel_pose_sequence(anny_body, "arms_up", 12)
    assert len(poses) == 12
    for side in ("L", "R"):
        sh0 = _posed_joint(anny_body, poses[0], f"upperarm01.{side}")
        el0 = _posed_joint(anny_body, poses[0], f"lowerarm01.{side}")
        el1 = _posed_joint(anny_body, poses[-1], f"lowerarm01.{side}")
        sh1 = _posed_joint(anny_body, poses[-1], f"upperarm01.{side}")
        assert el0[2] < sh0[2]  # A-pose at rest: elbows below the shoulders
        assert el1[2] > sh1[2] + 0.1, (side, el1, sh1)  # raised: well above
        assert np.sign(el1[0] - sh1[0]) == np.sign(el0[0] - sh0[0])  # sideways, not crossed over
        up = (el1 - sh1) / np.linalg.norm(el1 - sh1)
        assert np.degrees(np.arcsin(up[2])) == pytest.approx(65.0, abs=8.0)
    lifts = [_posed_joint(anny_body, p, "lowerarm01.L")[2] for p in poses]
    assert all(b >= a - 1e-9 for a, b in zip(lifts, lifts[1:]))  # monotone, then held


def test_walk_cycle_alternates_legs_and_loops(anny_body):
    from reconstruct.body.novel_poses import walk_cycle

    poses = walk_cycle(anny_body, 20)
    zl = np.array([_posed_joint(anny_body, p, "lowerleg01.L")[2] for p in poses])  # knee heights
    zr = np.array([_posed_joint(anny_body, p, "lowerleg01.R")[2] for p in poses])
    assert zl.max() - zl.min() > 0.05 and zr.max() - zr.min() > 0.05  # both knees lift
    assert np.argmax(zl) != np.argmax(zr)
    assert abs(int(np.argmax(zl)) - int(np.argmax(zr))) == 10  # half a cycle apart
    # forward (-Y): a lifted knee comes forward
    yl = _posed_joint(anny_body, poses[int(np.argmax(zl))], "lowerleg01.L")[1]
    assert yl < _posed_joint(anny_body, poses[0], "lowerleg01.L")[1] - 0.05
    # the cycle loops: the step after the last frame is the first
    d_wrap = np.abs(poses[-1].joint_rotations - poses[0].joint_rotations).max()
    d_step = np.abs(poses[1].joint_rotations - poses[0].joint_rotations).max()
    assert d_wrap <= 1.5 * d_step


def test_base_pose_and_bad_names(anny_body):
    from reconstruct.body.novel_poses import novel_pose_sequence
    from reconstruct.body.pose import BodyPose

    base = BodyPose(np.zeros((anny_body.num_joints, 3)), np.array([0, 0, 0.3]), np.array([0.1, 0.2, 0.0]))
    poses = novel_pose_sequence(anny_body, "walk", 6, base=base)
    assert all(np.allclose(p.global_orient, base.global_orient) for p in poses)
    assert np.allclose(poses[0].transl[:2], base.transl[:2])
    with pytest.raises(ValueError, match="walk, arms_up"):
        novel_pose_sequence(anny_body, "moonwalk")
    with pytest.raises(ValueError, match="at least 2"):
        novel_pose_sequence(anny_body, "walk", 1)
