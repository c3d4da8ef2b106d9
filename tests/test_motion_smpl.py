"""SMPL-family .npz sequences (reconstruct.motion.smpl_npz): the layouts, refusing pickles and broken
files, the SMPL body round trip, and the synthetic scene's Anny motion carried through an SMPL file."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import smpl_synth as S

from reconstruct.body import smpl_backend as B
from reconstruct.body.spec import smpl_body_spec
from reconstruct.motion import MotionFileError, load_motion, retarget
from reconstruct.motion.body_kinematics import BodySkeleton
from reconstruct.motion.rotations import (
    matrix_to_rotvec,
    rotation_between,
    rotvec_to_matrix,
)
from reconstruct.motion.smpl_npz import NOMINAL_JOINTS, SMPL_PARENTS

BETAS = np.linspace(-0.5, 0.5, 10)
C = B.SMPL_TO_BODY


def angle_deg(a, b) -> float:
    c = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(np.clip(c, -1.0, 1.0)))


def amass_motion(T: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(T,72) SMPL poses standing in a Z-up world (AMASS style: the root turns SMPL's Y up into Z up)
    and (T,3) translations walking along +X; hand joints (22, 23) at zero."""
    rng = np.random.default_rng(seed)
    full = rng.normal(0.0, 0.3, (T, 72))
    full[:, 66:] = 0.0
    for t in range(T):
        yaw = 0.4 + 0.1 * t
        R = rotvec_to_matrix(np.array([0.0, 0.0, yaw])) @ rotvec_to_matrix(np.array([math.pi / 2, 0.0, 0.0])) \
            @ rotvec_to_matrix(rng.normal(0.0, 0.1, 3))
        full[t, :3] = matrix_to_rotvec(R)
    trans = np.stack([0.05 * np.arange(T), 0.01 * np.arange(T), 0.9 + 0.01 * rng.normal(size=T)], 1)
    return full, trans


def save(path, layout: str, full: np.ndarray, trans: np.ndarray, fps_key: str | None = "mocap_framerate", fps=60.0):
    T = full.shape[0]
    arrays = {"trans": trans, "betas": np.zeros(16), "gender": np.array("neutral")}
    if layout == "smpl":
        arrays["poses"] = full
    elif layout == "smplh":
        arrays["poses"] = np.concatenate([full[:, :66], np.random.default_rng(1).normal(0, 0.3, (T, 90))], 1)
    elif layout == "smplx":
        arrays["poses"] = np.concatenate([full[:, :66], np.random.default_rng(2).normal(0, 0.3, (T, 99))], 1)
    elif layout == "split":
        arrays["root_orient"], arrays["pose_body"] = full[:, :3], full[:, 3:66]
    elif layout in ("smplx-lib", "smplx-lib rotmat", "smpl-lib 23 joints"):
        # the smplx library's keyword names (EasyMocap, SMPLer-X and the like), with 'transl'
        del arrays["trans"]
        arrays["transl"] = trans[:, None] if layout == "smplx-lib" else trans
        if layout == "smplx-lib":
            arrays["global_orient"], arrays["body_pose"] = full[:, :3], full[:, 3:66]
        elif layout == "smplx-lib rotmat":
            arrays["global_orient"] = rotvec_to_matrix(full[:, None, :3])
            arrays["body_pose"] = rotvec_to_matrix(full[:, 3:66].reshape(T, 21, 3))
        else:
            hands = np.random.default_rng(3).normal(0, 0.3, (T, 6))
            arrays["global_orient"] = full[:, :3]
            arrays["body_pose"] = np.concatenate([full[:, 3:66], hands], 1).reshape(T, 23, 3)
    elif layout == "aist++":
        del arrays["trans"]
        arrays["smpl_poses"], arrays["smpl_trans"], arrays["smpl_scaling"] = full, trans * 93.5, np.array([93.5])
    if fps_key:
        arrays[fps_key] = np.array(fps)
    np.savez(path, **arrays)
    return path


@pytest.fixture(scope="module")
def smpl_body(tmp_path_factory):
    folder = S.write_model(tmp_path_factory.mktemp("smpl"), fmt="npz").parent
    return smpl_body_spec(BETAS, "neutral", folder).build()


@pytest.mark.parametrize("layout", ["smpl", "smplh", "smplx", "split", "smplx-lib", "smplx-lib rotmat",
                                    "smpl-lib 23 joints", "aist++"])
def test_layouts_read_the_22_body_joints(tmp_path, layout):
    full, trans = amass_motion(5)
    clip = load_motion(save(tmp_path / f"{layout}.npz", layout, full, trans))
    assert clip.num_frames == 5 and clip.fps == 60.0 and clip.skeleton.num_joints == 22
    np.testing.assert_allclose(matrix_to_rotvec(clip.local_rotations), full[:, :66].reshape(5, 22, 3), atol=1e-9)
    np.testing.assert_allclose(clip.root_positions - NOMINAL_JOINTS[0], trans, atol=1e-12)
    # the world is Z up: up maps to up
    np.testing.assert_allclose(clip.world_to_body[2], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(clip.rest_to_body, C)


@pytest.mark.parametrize("what,arrays,pattern", [
    ("matrices that are not rotations", {"global_orient": np.tile(2 * np.eye(3), (4, 1, 1, 1)),
                                         "body_pose": np.tile(np.eye(3), (4, 21, 1, 1))},
     r"'global_orient' holds 3x3 matrices that are not rotations"),
    ("a body_pose of 20 joints", {"global_orient": np.zeros((4, 3)), "body_pose": np.zeros((4, 60))},
     r"'body_pose' has shape \(4, 60\), expected \(T, 63\), \(T, 21, 3\), \(T, 21, 3, 3\) or \(T, 69\)"),
    ("frames that disagree", {"global_orient": np.zeros((4, 3)), "body_pose": np.zeros((5, 63))},
     r"'global_orient' has 4 frames, 'body_pose' 5"),
    ("a bad smpl_scaling", {"smpl_poses": np.zeros((4, 72)), "smpl_trans": np.zeros((4, 3)), "smpl_scaling": np.array([0.0])},
     r"'smpl_scaling' must be one positive number"),
])
def test_library_layouts_refuse_what_they_cannot_read(tmp_path, what, arrays, pattern):
    np.savez(tmp_path / "m.npz", **arrays)
    with pytest.raises(MotionFileError, match=pattern):
        load_motion(tmp_path / "m.npz")


@pytest.mark.parametrize("key", ["mocap_framerate", "mocap_frame_rate", "fps", None])
def test_frame_rate_keys(tmp_path, key):
    full, trans = amass_motion(3)
    clip = load_motion(save(tmp_path / "a.npz", "smpl", full, trans, fps_key=key, fps=120.0))
    if key is None:
        assert clip.fps == 30.0 and any("assumed 30 fps" in n for n in clip.notes)
    else:
        assert clip.fps == 120.0


def test_pickled_and_broken_npz_are_refused(tmp_path):
    full, trans = amass_motion(3)
    p = tmp_path / "objects.npz"
    np.savez(p, poses=full, trans=trans, gender=np.array(["male"], dtype=object))
    with pytest.raises(MotionFileError, match=r"objects\.npz: array 'gender' holds pickled Python objects; such files are refused"):
        load_motion(p)
    p = tmp_path / "pickle.npz"
    p.write_bytes(pickle.dumps({"poses": full}))
    with pytest.raises(MotionFileError, match=r"pickle\.npz: not an \.npz archive \(it holds pickled data, which is refused"):
        load_motion(p)
    p = tmp_path / "empty.npz"
    np.savez(p, poses=np.zeros((0, 72)), trans=np.zeros((0, 3)), mocap_framerate=30.0)
    with pytest.raises(MotionFileError, match=r"empty\.npz: empty motion \(0 frames\)"):
        load_motion(p)
    p = tmp_path / "narrow.npz"
    np.savez(p, poses=np.zeros((4, 30)))
    with pytest.raises(MotionFileError, match=r"narrow\.npz: 'poses' has shape \(4, 30\), expected \(T, 3K\)"):
        load_motion(p)
    p = tmp_path / "nokeys.npz"
    np.savez(p, something=np.zeros(3))
    with pytest.raises(MotionFileError, match=r"nokeys\.npz: no SMPL pose arrays.*found keys \['something'\]"):
        load_motion(p)
    p = tmp_path / "frames.npz"
    np.savez(p, poses=np.zeros((4, 72)), trans=np.zeros((3, 3)))
    with pytest.raises(MotionFileError, match=r"'trans' has 3 frames, the poses 4"):
        load_motion(p)
    p = tmp_path / "nan.npz"
    bad = np.zeros((4, 72))
    bad[2, 5] = np.nan
    np.savez(p, poses=bad)
    with pytest.raises(MotionFileError, match=r"'poses' contains non-finite values"):
        load_motion(p)


def test_smpl_sequence_on_the_smpl_body_gives_the_same_poses(tmp_path, smpl_body):
    """npz made from SMPL poses -> SMPL body: the same joint rotations (to 1e-6 rad) and the same
    posed skeleton in the file's world (to 1e-6 m), up to the world-axes turn and a shift."""
    T = 8
    full, trans = amass_motion(T, seed=3)
    clip = load_motion(save(tmp_path / "seq.npz", "smplh", full, trans))
    res = retarget(clip, smpl_body, keep_heading=True)
    assert res.num_frames == T and res.fps == 60.0
    assert res.scale == pytest.approx(1.0)
    got = np.stack([p.joint_rotations for p in res.poses])
    want = full.reshape(T, 24, 3) @ C.T
    np.testing.assert_allclose(got[:, 1:22], want[:, 1:22], atol=1e-6)
    np.testing.assert_allclose(got[:, 22:], 0.0, atol=1e-9)
    mine = np.stack([smpl_body.posed_joints(p).numpy() for p in res.poses])
    ref = np.stack([smpl_body.posed_joints(B.smpl_body_pose(full[t], trans[t])).numpy() for t in range(T)])
    shift = mine - ref @ clip.world_to_body.T
    assert np.abs(shift - shift[0, 0]).max() < 1e-6


def test_anny_scene_motion_through_an_smpl_file(tmp_path, small_scene):
    """The synthetic scene's Anny walk written as an SMPL-layout file (world rotations of the mapped
    bones, rest directions taken from the nominal SMPL T-pose) drives Anny's limbs back to the
    scene's bone directions (within 1 degree)."""
    from reconstruct.data.synthetic.motion import walk_in_place

    body = small_scene.body_model()
    L = body.bone_labels
    poses = walk_in_place(L, 24, 20.0, np.random.default_rng(0))
    sk = BodySkeleton(body)
    E, p, G, t = sk.forward_poses(poses)
    W = np.einsum("tab,tjbc->tjac", G, E)  # world rotations relative to the zero pose
    heads = np.einsum("tab,tjb->tja", G, p) + t[:, None]
    toes = [i for i, label in enumerate(L) if label.startswith("toe") and label.endswith("-1.L")]
    toes_r = [i for i, label in enumerate(L) if label.startswith("toe") and label.endswith("-1.R")]
    bone = {0: "root", 1: "upperleg01.L", 2: "upperleg01.R", 3: "spine04", 4: "lowerleg01.L", 5: "lowerleg01.R",
            6: "spine03", 7: "foot.L", 8: "foot.R", 9: "spine02", 10: "foot.L", 11: "foot.R", 12: "neck01",
            13: "clavicle.L", 14: "clavicle.R", 15: "head", 16: "upperarm01.L", 17: "upperarm01.R",
            18: "lowerarm01.L", 19: "lowerarm01.R", 20: "wrist.L", 21: "wrist.R"}
    tip = {1: 4, 2: 5, 4: 7, 5: 8, 12: 15, 13: 16, 14: 17, 16: 18, 17: 19, 18: 20, 19: 21}
    z = sk.zero_heads
    anny_tip = {7: z[toes].mean(0), 8: z[toes_r].mean(0)}
    rest = NOMINAL_JOINTS @ C.T  # the nominal SMPL T-pose in body axes
    align = {}
    for j, k in tip.items():
        db = z[L.index(bone[k])] - z[L.index(bone[j])]
        align[j] = rotation_between(rest[k] - rest[j], db)
    for j, k in ((7, 10), (8, 11)):
        align[j] = rotation_between(rest[k] - rest[j], anny_tip[j] - z[L.index(bone[j])])
    Q = np.empty((len(poses), 22, 3, 3))
    for j in range(22):
        S_j = align.get(j, align.get(SMPL_PARENTS[j], np.eye(3)) if j in (20, 21, 10, 11) else np.eye(3))
        Q[:, j] = W[:, L.index(bone[j])] @ S_j @ C  # file world = body world (Z up)
    local = Q.copy()
    for j in range(1, 22):
        local[:, j] = np.swapaxes(Q[:, SMPL_PARENTS[j]], -1, -2) @ Q[:, j]
    full = np.zeros((len(poses), 72))
    full[:, :66] = matrix_to_rotvec(local).reshape(len(poses), 66)
    trans = heads[:, L.index("root")] - NOMINAL_JOINTS[0]
    clip = load_motion(save(tmp_path / "anny.npz", "smpl", full, trans, fps=20.0))
    np.testing.assert_allclose(clip.world_to_body, np.eye(3), atol=1e-12)
    res = retarget(clip, body, keep_heading=True)
    pairs = [("upperleg01.L", "lowerleg01.L"), ("upperleg01.R", "lowerleg01.R"), ("lowerleg01.L", "foot.L"),
             ("lowerleg01.R", "foot.R"), ("upperarm01.L", "lowerarm01.L"), ("upperarm01.R", "lowerarm01.R"),
             ("lowerarm01.L", "wrist.L"), ("lowerarm01.R", "wrist.R"), ("clavicle.L", "upperarm01.L"),
             ("neck01", "head")]
    worst = 0.0
    for f, (mine, scene_pose) in enumerate(zip(res.poses, poses)):
        a, b = body.posed_joints(mine).numpy(), body.posed_joints(scene_pose).numpy()
        for u, v in pairs:
            worst = max(worst, angle_deg(a[L.index(v)] - a[L.index(u)], b[L.index(v)] - b[L.index(u)]))
    assert worst < 1.0, worst
