"""Reading BVH files (reconstruct.motion.bvh): files written by an independent library (bvhio),
rotation orders, units/axes detection, and clear errors for broken files."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from reconstruct.motion import MotionFileError, load_motion

try:  # the independent writer (the 'test' extra); the broken-file tests below need neither
    with warnings.catch_warnings():  # bvhio imports PyGLM under its old name
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import bvhio
        import glm
except ImportError:  # pragma: no cover
    bvhio = glm = None
import motion_files  # noqa: E402

needs_bvhio = pytest.mark.skipif(bvhio is None, reason="bvhio (pip install bvhio) writes the test files")

# the CMU/Mixamo-like T-pose skeleton of tests/motion_files.py, without its finger
SKELETON = [j for j in motion_files.SKELETON if j[0] != "LeftHandIndex1"]
END_SITES = {"LeftToeBase": (0.0, 0.0, 5.0), "RightToeBase": (0.0, 0.0, 5.0), "Head": (0.0, 18.0, 0.0),
             "LeftHand": (10.0, 0.0, 0.0), "RightHand": (-10.0, 0.0, 0.0)}
# a mix of rotation orders, as files from different tools have
ORDERS = {"Hips": "ZXY", "LeftArm": "XYZ", "RightArm": "YXZ", "LeftForeArm": "ZYX", "LeftUpLeg": "YZX",
          "RightLeg": "XZY"}
# source (Y up, facing +Z, cm) -> body (Z up, facing -Y)
TO_BODY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def quat(axis, deg: float):
    return glm.angleAxis(math.radians(deg), glm.normalize(glm.vec3(*axis)))


def write_bvh(path: Path, rotations: dict[str, list], root_positions: list, frame_time: float = 1 / 30,
              joint_positions: bool = False) -> Path:
    """Writes the skeleton with bvhio. ``rotations``: joint -> per-frame glm quaternions (local,
    relative to the rest pose); joints not given stay at rest."""
    frames = len(root_positions)
    joints = {}
    for name, parent, offset in SKELETON:
        j = bvhio.BvhJoint(name, glm.vec3(*offset))
        order = ORDERS.get(name, "ZXY")
        rot = [f"{a}rotation" for a in order]
        j.Channels = (["Xposition", "Yposition", "Zposition"] if parent is None or joint_positions else []) + rot
        if name in END_SITES:
            j.EndSite = glm.vec3(*END_SITES[name])
        qs = rotations.get(name, [glm.quat()] * frames)
        pos = root_positions if parent is None else [glm.vec3(*offset)] * frames
        j.Keyframes = [bvhio.Pose(glm.vec3(*pos[f]), qs[f]) for f in range(frames)]
        joints[name] = j
        if parent is not None:
            joints[parent].Children.append(j)
    bvhio.writeBvh(str(path), bvhio.BvhContainer(joints["Hips"], frames, frame_time), percision=9)
    return path


def expected_world(rotations: dict[str, list], frame: int, root=None) -> tuple[dict, dict]:
    """Independent forward kinematics with glm: joint -> world quaternion and position (cm)."""
    wq, wp = {}, {}
    for name, parent, offset in SKELETON:
        q = rotations.get(name, None)
        q = q[frame] if q is not None else glm.quat()
        if parent is None:
            wq[name], wp[name] = q, glm.vec3(*(offset if root is None else root))
        else:
            wq[name] = wq[parent] * q
            wp[name] = wp[parent] + wq[parent] * glm.vec3(*offset)
    return wq, wp


@needs_bvhio
def test_reads_bvhio_file_with_mixed_rotation_orders(tmp_path):
    rng = np.random.default_rng(0)
    T = 5
    rots = {name: [quat(rng.normal(size=3), rng.uniform(-60, 60)) for _ in range(T)] for name, _, _ in SKELETON}
    roots = [(rng.normal() * 10, 95 + rng.normal(), rng.normal() * 10) for _ in range(T)]
    path = write_bvh(tmp_path / "mixed.bvh", rots, roots, frame_time=0.04)
    clip = load_motion(path)
    assert clip.num_frames == T and clip.fps == pytest.approx(25.0)
    assert clip.skeleton.names[:3] == ("Hips", "LeftUpLeg", "LeftLeg")
    assert clip.metres_per_unit == 0.01  # centimetres, from the leg length
    np.testing.assert_allclose(clip.world_to_body, TO_BODY, atol=1e-12)  # Y up, facing +Z detected
    names = list(clip.skeleton.names)
    Q, P = clip.world()
    for f in range(T):
        wq, wp = expected_world(rots, f, roots[f])
        for name in names:
            j = names.index(name)
            ref = np.array(glm.mat3_cast(wq[name]).to_list()).T  # glm is column-major
            np.testing.assert_allclose(Q[f, j], ref, atol=1e-6)
            np.testing.assert_allclose(P[f, j], np.array(wp[name].to_list()), atol=1e-4)


@needs_bvhio
def test_joint_position_channels_are_read_and_noted(tmp_path):
    T = 3
    rots = {"LeftArm": [quat((0, 0, 1), -30.0)] * T}
    path = write_bvh(tmp_path / "pos.bvh", rots, [(0, 95, 0)] * T, joint_positions=True)
    clip = load_motion(path)
    assert clip.num_frames == T
    j = clip.skeleton.names.index("LeftArm")
    np.testing.assert_allclose(clip.local_rotations[:, j], np.broadcast_to(
        np.array(glm.mat3_cast(quat((0, 0, 1), -30.0)).to_list()).T, (T, 3, 3)), atol=1e-6)


def test_z_up_metre_skeleton_is_detected(tmp_path):
    text = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0.95
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT LeftUpLeg
  { OFFSET 0.09 0 -0.05 CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT LeftLeg { OFFSET 0 0 -0.43 CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT LeftFoot { OFFSET 0 0 -0.42 CHANNELS 3 Zrotation Xrotation Yrotation
        End Site { OFFSET 0 -0.1 0 } } } }
  JOINT RightUpLeg
  { OFFSET -0.09 0 -0.05 CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT RightLeg { OFFSET 0 0 -0.43 CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT RightFoot { OFFSET 0 0 -0.42 CHANNELS 3 Zrotation Xrotation Yrotation
        End Site { OFFSET 0 -0.1 0 } } } }
  JOINT Head { OFFSET 0 0 0.7 CHANNELS 3 Zrotation Xrotation Yrotation End Site { OFFSET 0 0 0.2 } }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 0 0.95 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
0 0 0.95 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
"""
    path = tmp_path / "zup.bvh"
    path.write_text(text)
    clip = load_motion(path)
    assert clip.metres_per_unit == 1.0
    # Z up, the left leg on +X, so facing -Y: already the body's axes
    np.testing.assert_allclose(clip.world_to_body, np.eye(3), atol=1e-12)
    # an explicit override wins
    clip2 = load_motion(path, up="+Z", forward="+Y")
    np.testing.assert_allclose(clip2.world_to_body @ np.array([0.0, 1.0, 0.0]), [0.0, -1.0, 0.0], atol=1e-12)


# ----- broken files -------------------------------------------------------------------------------
GOOD = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 10 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.033333
0 90 0 0 0 0 0 0 0
0 90 0 0 0 10 0 0 0
"""


def _write(tmp_path, text, name="bad.bvh"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_good_minimal_file_reads(tmp_path):
    clip = load_motion(_write(tmp_path, GOOD, "good.bvh"))
    assert clip.num_frames == 2
    assert clip.local_rotations.shape == (2, 2, 3, 3)


@pytest.mark.parametrize("case,text,pattern", [
    ("truncated in the motion", GOOD.rsplit("\n", 2)[0] + "\n", r"bad\.bvh:19: truncated: 'Frames: 2' but the file ends after 1 frames"),
    ("truncated mid-frame", GOOD[: GOOD.rindex("0 0 0\n")], r"bad\.bvh:20: truncated: frame 1 has 6 of 9 values"),
    ("truncated in the hierarchy", GOOD[: GOOD.index("    End Site")], r"bad\.bvh:\d+: the file ends where the end of joint 'Spine'"),
    ("no motion section", GOOD[: GOOD.index("MOTION")], r"no MOTION section \(truncated file\?\)"),
    ("channel count mismatch", GOOD.replace("CHANNELS 3 Zrotation", "CHANNELS 4 Zrotation"),
     r"bad\.bvh:9: CHANNELS of 'Spine': the count says 4 channels, 3 are listed"),
    ("frame length mismatch", GOOD.replace("0 90 0 0 0 10 0 0 0", "0 90 0 0 0 10 0 0 0 7"),
     r"bad\.bvh:20: frame 1 has 10 values, the hierarchy has 9 channels"),
    ("unsupported channel", GOOD.replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation Yscale"),
     r"bad\.bvh:9: unsupported channel 'Yscale' on joint 'Spine'"),
    ("empty motion", GOOD.replace("Frames: 2", "Frames: 0").rsplit("0 90", 2)[0], r"bad\.bvh:17: empty motion: Frames: 0"),
    ("non-numeric value", GOOD.replace("0 90 0 0 0 10", "0 90 0 0 abc 10"), r"bad\.bvh:20: frame 1: non-numeric value 'abc'"),
    ("non-numeric offset", GOOD.replace("OFFSET 0 10 0\n    CHANNELS", "OFFSET 0 ten 0\n    CHANNELS"),
     r"bad\.bvh:8: OFFSET of 'Spine': non-numeric value 'ten'"),
    ("non-numeric frame time", GOOD.replace("Frame Time: 0.033333", "Frame Time: fast"), r"bad\.bvh:18: Frame Time: non-numeric value 'fast'"),
    ("more frames than declared", GOOD + "0 90 0 0 0 0 0 0 0\n", r"bad\.bvh:21: more frames than 'Frames: 2' says"),
    ("not a BVH", "hello\n", r"bad\.bvh:1: expected 'HIERARCHY', found 'hello'"),
    ("empty file", "", r"bad\.bvh:1: empty file"),
])
def test_broken_files_are_refused_naming_file_and_line(tmp_path, case, text, pattern):
    with pytest.raises(MotionFileError, match=pattern):
        load_motion(_write(tmp_path, text))


@pytest.mark.parametrize("case,data,note", [
    ("a byte-order mark (Windows tools)", ("\ufeff" + GOOD).encode("utf-8"), None),
    ("Windows line ends", GOOD.replace("\n", "\r\n").encode("utf-8"), None),
    ("values against the colon", GOOD.replace("Frames: 2", "Frames:2").replace("Time: 0.033333", "Time:0.033333").encode(),
     None),
    ("a joint name in a code page", GOOD.replace("Spine", "Colonne_\u00e9").encode("latin-1"), "not UTF-8: read as Latin-1"),
])
def test_files_as_other_tools_write_them_read_like_the_plain_one(tmp_path, case, data, note):
    """The same two frames as ``GOOD`` written the ways exporters and editors write BVH: each reads
    to the same rotations and root path (a byte-order mark was 'expected HIERARCHY', a code page
    'not a text file', 'Frames:2' 'expected Frames:'); a file that is not UTF-8 says so in a note."""
    plain = load_motion(_write(tmp_path, GOOD, "good.bvh"))
    p = tmp_path / "other.bvh"
    p.write_bytes(data)
    clip = load_motion(p)
    assert clip.num_frames == 2 and clip.fps == pytest.approx(plain.fps)
    assert np.allclose(clip.local_rotations, plain.local_rotations)
    assert np.allclose(clip.root_positions, plain.root_positions)
    assert (note is None) == (not any("not UTF-8" in n for n in clip.notes))
    if note:
        assert any(note in n for n in clip.notes) and clip.skeleton.names[1] == "Colonne_\u00e9"


def test_a_binary_file_named_bvh_is_refused(tmp_path):
    p = tmp_path / "model.bvh"
    p.write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00" + bytes(range(256)))
    with pytest.raises(MotionFileError, match=r"model\.bvh: not a text file \(BVH files are text; found binary data"):
        load_motion(p)


def test_unknown_suffix_and_pickles_refused(tmp_path):
    with pytest.raises(MotionFileError, match="unsupported motion file type '.c3d'"):
        load_motion(_write(tmp_path, "x", "a.c3d"))
    with pytest.raises(MotionFileError, match="pickle files are refused"):
        load_motion(_write(tmp_path, "x", "a.pkl"))
    with pytest.raises(MotionFileError, match="no such motion file"):
        load_motion(tmp_path / "missing.bvh")
