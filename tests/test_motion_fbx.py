"""Binary FBX skeletal animation (reconstruct.motion.fbx, fbx_binary) checked against Blender.

The references in ``tests/data/fbx`` were written by ``scripts/make_fbx_fixtures.py`` with Blender
4.5 (``bpy``): Blender's own FBX and glTF exports of a BVH walk (``walk.bvh``) must read to the BVH
file's clip and retarget to the same poses; a rig written here the way Maya writes one (joint orients
as PreRotation, PostRotation, other Euler orders, a pivot, a turned and scaled armature, Z up) must
put every joint where Blender's FBX import puts it, in every frame. Broken files are refused naming
the file; nothing in an FBX file is run.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from fbx_files import (
    FPS,
    FRAMES,
    PIVOT,
    I32,
    P,
    Rec,
    fbx_bytes,
    joint_orient_rig,
    scene,
    write_joint_orient_fbx,
)

from reconstruct.motion import MotionFileError, load_motion, retarget
from reconstruct.motion.fbx import euler

DATA = Path(__file__).parent / "data" / "fbx"


def _same_clip(clip, bvh, rot_atol=1e-5):
    scale = clip.metres_per_unit / bvh.metres_per_unit
    assert clip.skeleton.names == bvh.skeleton.names
    np.testing.assert_array_equal(clip.skeleton.parents, bvh.skeleton.parents)
    np.testing.assert_allclose(clip.skeleton.offsets * scale, bvh.skeleton.offsets, atol=1e-3)
    assert clip.num_frames == bvh.num_frames and clip.fps == pytest.approx(bvh.fps, rel=1e-5)
    np.testing.assert_allclose(clip.local_rotations, bvh.local_rotations, atol=rot_atol)
    np.testing.assert_allclose(clip.root_positions * scale, bvh.root_positions, atol=1e-3)
    np.testing.assert_allclose(clip.rest_to_body, bvh.rest_to_body, atol=1e-9)


@pytest.mark.parametrize("name", ["blender_walk.fbx", "blender_walk.glb"])
def test_blenders_exports_read_to_the_bvh_files_clip_and_poses(anny_body, name):
    """Blender's FBX (rest pose only in the bind pose: the models' own values are frame 5 of the
    walk) and glTF exports of the BVH walk: the same skeleton, rotations to 1e-5, root path and poses."""
    bvh = load_motion(DATA / "walk.bvh")
    clip = load_motion(DATA / name)
    _same_clip(clip, bvh)
    if name.endswith(".fbx"):
        assert clip.format == "fbx" and clip.metres_per_unit == pytest.approx(0.01)
        assert "rest pose: the bind pose" in clip.notes
    # Blender bakes every channel of every bone, most of them constant: no notes about them
    assert not [n for n in clip.notes if "ignored" in n or "above the skeleton move" in n], clip.notes
    a, b = retarget(bvh, anny_body), retarget(clip, anny_body)
    assert len(a.poses) == len(b.poses) == bvh.num_frames
    for pa, pb in zip(a.poses, b.poses):
        np.testing.assert_allclose(pb.joint_rotations, pa.joint_rotations, atol=1e-4)
        np.testing.assert_allclose(pb.global_orient, pa.global_orient, atol=1e-4)
        np.testing.assert_allclose(pb.transl, pa.transl, atol=1e-4)


def _kabsch(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(X.T @ Y)
    R = (U @ Vt).T
    assert np.linalg.det(R) > 0
    return R


def _subtree(clip, name: str) -> set[str]:
    names, parents = clip.skeleton.names, clip.skeleton.parents
    inside = {names.index(name)}
    for k in range(len(names)):
        if parents[k] in inside:
            inside.add(k)
    return {names[k] for k in inside}


@pytest.mark.parametrize("fixture", ["joint_orient.fbx", "blender_walk.fbx"])
def test_every_joint_is_where_blenders_import_puts_it(fixture):
    """Forward kinematics of the clip against Blender's import of the same file, every joint in every
    frame (metres; Blender's scene is Z up, so the axes are matched by the best rotation, which must
    be a proper axis permutation). Joints under a rotation pivot keep their rest offsets in the clip
    (bone lengths are the avatar's), so there only the bones below them are compared."""
    clip = load_motion(DATA / fixture)
    ref = np.load(DATA / fixture.replace(".fbx", ".blender.npz"))
    names = [str(n) for n in ref["names"]]
    assert sorted(names) == sorted(clip.skeleton.names)
    assert clip.fps == pytest.approx(float(ref["fps"]))
    _, P = clip.world()
    idx = [clip.skeleton.names.index(n) for n in names]
    X, Y = P[:, idx] * clip.metres_per_unit, ref["heads"]
    assert X.shape == Y.shape
    pivoted = set().union(*(_subtree(clip, n) for n in PIVOT)) if fixture == "joint_orient.fbx" else set()
    exact = [k for k, n in enumerate(names) if n not in pivoted]
    R = _kabsch(X[:, exact].reshape(-1, 3), Y[:, exact].reshape(-1, 3))
    np.testing.assert_allclose(np.abs(R), np.round(np.abs(R)), atol=1e-6)  # an axis permutation
    np.testing.assert_allclose(X[:, exact] @ R.T, Y[:, exact], atol=2e-5)
    for k, n in enumerate(names):
        p = clip.skeleton.parents[clip.skeleton.names.index(n)]
        if p < 0 or n in PIVOT:  # the bone that ends at a pivoted joint changes length as it turns
            continue
        kp = names.index(clip.skeleton.names[p])
        np.testing.assert_allclose((X[:, k] - X[:, kp]) @ R.T, Y[:, k] - Y[:, kp], atol=2e-5, err_msg=n)
    if pivoted:  # the pivot moves the joint's origin as it turns: the clip does not follow that
        assert np.abs(X[:, [names.index(n) for n in pivoted]] @ R.T - Y[:, [names.index(n) for n in pivoted]]).max() > 1e-3


def test_a_bvh_root_bone_is_read_as_the_armature_as_blender_places_it(anny_body):
    """``root_bone.bvh``: the walk under a 'root' bone that walks 10 cm and turns 12 degrees a frame,
    the hips its only child with their own position channels. The clip starts at the hips, the root
    bone's motion carried into theirs, and every joint is where Blender's BVH import puts it."""
    clip = load_motion(DATA / "root_bone.bvh")
    plain = load_motion(DATA / "walk.bvh")
    assert clip.skeleton.names == plain.skeleton.names and clip.skeleton.names[0] == "Hips"
    assert "'root' above 'Hips' read as the armature: its motion is the root's" in clip.notes
    assert not [n for n in clip.notes if "position channels" in n]  # the hips' own are the root path
    ref = np.load(DATA / "root_bone.blender.npz")
    names = [str(n) for n in ref["names"]]
    _, P = clip.world()
    idx = [clip.skeleton.names.index(n) for n in names if n != "root"]
    X = P[:, idx] * clip.metres_per_unit
    Y = ref["heads"][:, [names.index(n) for n in names if n != "root"]]
    R = _kabsch(X.reshape(-1, 3), Y.reshape(-1, 3))
    np.testing.assert_allclose(np.abs(R), np.round(np.abs(R)), atol=1e-6)
    np.testing.assert_allclose(X @ R.T, Y, atol=2e-5)
    # the same walk with the root bone's motion: the hips travel 10 cm a frame further along X
    a, b = retarget(plain, anny_body), retarget(clip, anny_body)
    assert not np.allclose([p.transl for p in a.poses], [p.transl for p in b.poses], atol=0.05)


def test_the_joint_orient_fixture_is_what_the_writer_writes(tmp_path):
    """The stored file (written where Blender ran, with another numpy) is the writer's rig, record
    for record, up to the last digits of the trigonometry."""
    from reconstruct.motion.fbx_binary import parse_fbx

    fresh = write_joint_orient_fbx(tmp_path / "j.fbx")
    stored = DATA / "joint_orient.fbx"
    trees = [parse_fbx(p, p.read_bytes()) for p in (fresh, stored)]
    assert trees[0][0] == trees[1][0] == 7500

    def same(a, b):
        assert (a.name, len(a.values), len(a.children)) == (b.name, len(b.values), len(b.children))
        for u, v in zip(a.values, b.values):
            if isinstance(u, (float, np.ndarray)):
                np.testing.assert_allclose(u, v, rtol=0, atol=1e-9)
            else:
                assert u == v
        for c, d in zip(a.children, b.children):
            same(c, d)

    same(trees[0][1], trees[1][1])


def test_a_maya_rig_at_rest_is_the_identity_and_stands_up(tmp_path):
    """The joint-orient rig's first frame is its rest pose: identity local rotations, rest positions
    where the writer put them; the armature's turn stands the person up in the Z-up world."""
    clip = load_motion(DATA / "joint_orient.fbx")
    _, world_rest = joint_orient_rig()
    for k, n in enumerate(clip.skeleton.names):
        np.testing.assert_allclose(clip.skeleton.rest_positions()[k], world_rest[n], atol=1e-9)
    np.testing.assert_allclose(clip.local_rotations[0], np.broadcast_to(np.eye(3), clip.local_rotations[0].shape),
                               atol=1e-12)
    np.testing.assert_allclose(clip.rest_to_body, np.eye(3), atol=1e-12)  # Z up, facing -Y
    assert clip.num_frames == FRAMES and clip.fps == FPS and clip.metres_per_unit == pytest.approx(0.01)
    assert any("rotation pivots on 1 joint:" in n for n in clip.notes)


def test_mixamo_joint_names_retarget_like_plain_ones(anny_body, tmp_path):
    """Mixamo's FBX names every joint 'mixamorig:...': the same rig so named drives the same bones
    into the same poses."""
    plain = load_motion(DATA / "joint_orient.fbx")
    mixamo = load_motion(write_joint_orient_fbx(tmp_path / "mixamo.fbx", prefix="mixamorig:"))
    assert mixamo.skeleton.names[0] == "mixamorig:Hips"
    a, b = retarget(plain, anny_body), retarget(mixamo, anny_body)
    assert [m.body_bone for m in a.mapping] == [m.body_bone for m in b.mapping] and len(a.mapping) >= 15
    for pa, pb in zip(a.poses, b.poses):
        np.testing.assert_allclose(pb.joint_rotations, pa.joint_rotations, atol=1e-9)
        np.testing.assert_allclose(pb.transl, pa.transl, atol=1e-9)


def test_an_armature_written_as_a_joint_and_a_root_bone_are_read_as_the_armature(tmp_path):
    """Blender writes its armature as a LimbNode or Root when asked to, and game rigs put a 'root'
    bone above the pelvis to carry root motion: the chain of single-child joints above the first
    joint that branches goes above the skeleton, its motion carried into the root's. The rig with
    its Armature as a LimbNode reads to the rig with it as a Null; a root bone's walk adds to the hips'."""
    def rig(kind, root_bone=False):
        models, _ = joint_orient_rig()
        models[0]["kind"] = kind
        if root_bone:  # a 'root' bone between the armature and the hips carries the walk forward
            walk = np.stack([np.zeros(FRAMES), 5.0 * np.arange(FRAMES), np.zeros(FRAMES)], 1)
            models.insert(1, {"name": "root", "kind": "LimbNode", "parent": 0, "curves": {"Lcl Translation": walk}})
            for m in models[2:]:
                m["parent"] = m["parent"] + 1 if m["parent"] else 1
        p = tmp_path / f"{kind}{root_bone}.fbx"
        p.write_bytes(fbx_bytes(scene(models, FRAMES, FPS, up_axis=2)))
        return load_motion(p)

    null, limb = rig("Null"), rig("LimbNode")
    assert limb.skeleton.names == null.skeleton.names and limb.skeleton.names[0] == "Hips"
    assert "'Armature' above 'Hips' read as the armature: its motion is the root's" in limb.notes
    np.testing.assert_allclose(limb.local_rotations, null.local_rotations, atol=1e-12)
    np.testing.assert_allclose(limb.root_positions, null.root_positions, atol=1e-9)
    game = rig("LimbNode", root_bone=True)
    assert game.skeleton.names == null.skeleton.names
    assert "'Armature', 'root' above 'Hips' read as the armature: their motion is the root's" in game.notes
    np.testing.assert_allclose(game.local_rotations, null.local_rotations, atol=1e-12)
    # the root bone's +Y 5 cm a frame in the armature, turned by its 90 degrees about X and scaled by 2
    step = np.stack([np.zeros(FRAMES), np.zeros(FRAMES), 10.0 * np.arange(FRAMES)], 1)
    np.testing.assert_allclose(game.root_positions - null.root_positions, step, atol=1e-9)


def test_a_rest_pose_that_does_not_stand_is_noted(anny_body, tmp_path):
    """Without a bind pose the rest is the models' own values, which Blender's exporter sets to the
    frame it exports at: a rest with a thigh lifted and the spine bent by 60 degrees is named in the
    retarget's notes; the standing rigs (the Maya rig, Blender's walk with its bind pose, the BVH) are not."""
    models, _ = joint_orient_rig()
    for m in models:
        if m["name"] in ("LeftUpLeg", "Spine"):
            m["props"].append(P("Lcl Rotation", "Lcl Rotation", "", "A", 60.0, 0.0, 0.0))
    p = tmp_path / "bent.fbx"
    p.write_bytes(fbx_bytes(scene(models, FRAMES, FPS, up_axis=2)))
    notes = [n for n in retarget(load_motion(p), anny_body).notes if "does not stand upright" in n]
    assert len(notes) == 1 and "left thigh" in notes[0] and "spine" in notes[0] and "right thigh" not in notes[0], notes
    for standing in ("joint_orient.fbx", "blender_walk.fbx", "walk.bvh"):
        assert not [n for n in retarget(load_motion(DATA / standing), anny_body).notes if "upright" in n], standing


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YZX", "YXZ", "ZXY", "ZYX"])
def test_euler_orders_match_scipys_extrinsic_rotations(order):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    a = rng.uniform(-170, 170, (20, 3))
    want = Rotation.from_euler(order.lower(), a[:, ["XYZ".index(c) for c in order]], degrees=True).as_matrix()
    np.testing.assert_allclose(euler(a, order), want, atol=1e-12)


def _one_bone(tmp_path, *, keys, values, flags=0x4, fps=30.0, time_mode=14, unit_cm=1.0, version=7400,
              compress=True, name="one.fbx", extra=None):
    """A two-joint skeleton whose child turns about X through ``values`` (degrees) at frame
    numbers ``keys`` (at ``fps``)."""
    ticks = np.round(np.asarray(keys, float) * (46186158000 / fps)).astype(np.int64)
    models = [{"name": "Hips", "kind": "LimbNode", "parent": None,
               "props": [P("Lcl Translation", "Lcl Translation", "", "A", 0.0, 95.0, 0.0)]},
              {"name": "Spine", "kind": "LimbNode", "parent": 0,
               "props": [P("Lcl Translation", "Lcl Translation", "", "A", 0.0, 10.0, 0.0)]}]
    if extra:
        extra(models)
    recs = scene(models, len(keys), fps, time_mode=time_mode, unit_cm=unit_cm)
    objects, links = recs[3].children, recs[4].children
    layer = next(o.values[0] for o in objects if o.name == "AnimationLayer")
    spine = next(o.values[0] for o in objects if o.name == "Model" and o.values[1].startswith("Spine"))
    objects += [Rec("AnimationCurveNode", 90001, "R\x00\x01AnimCurveNode", ""),
                Rec("AnimationCurve", 90002, "\x00\x01AnimCurve", "", children=[
                    Rec("KeyTime", ticks), Rec("KeyValueFloat", np.asarray(values, np.float32)),
                    Rec("KeyAttrFlags", np.array([flags], np.int32)), Rec("KeyAttrRefCount", np.array([len(keys)], np.int32))])]
    links += [Rec("C", "OO", 90001, layer), Rec("C", "OP", 90001, spine, "Lcl Rotation"),
              Rec("C", "OP", 90002, 90001, "d|X")]
    p = tmp_path / name
    p.write_bytes(fbx_bytes(recs, version=version, compress=compress))
    return p


def _x_angles(clip) -> np.ndarray:
    R = clip.local_rotations[:, 1]
    return np.degrees(np.arctan2(R[:, 2, 1], R[:, 1, 1]))


def test_keys_are_resampled_at_the_files_frame_rate(tmp_path):
    """Keys every other frame at 24 fps (TimeMode 11): linear keys are interpolated at the frames
    between; constant keys hold; without a TimeMode the keys' spacing gives the rate."""
    clip = load_motion(_one_bone(tmp_path, keys=[0, 2, 4, 8], values=[0, 20, 10, 50], fps=24.0, time_mode=11))
    assert clip.fps == 24.0 and clip.num_frames == 9
    np.testing.assert_allclose(_x_angles(clip), [0, 10, 20, 15, 10, 20, 30, 40, 50], atol=1e-4)
    held = load_motion(_one_bone(tmp_path, keys=[0, 2, 4, 8], values=[0, 20, 10, 50], fps=24.0, time_mode=11,
                                 flags=0x2, name="held.fbx"))
    np.testing.assert_allclose(_x_angles(held), [0, 0, 20, 20, 10, 10, 10, 10, 50], atol=1e-4)
    custom = load_motion(_one_bone(tmp_path, keys=[0, 1, 2], values=[0, 5, 10], fps=12.5, time_mode=14, name="c.fbx"))
    assert custom.fps == 12.5 and custom.num_frames == 3
    spaced = load_motion(_one_bone(tmp_path, keys=[0, 1, 2, 3], values=[0, 5, 10, 15], fps=60.0, time_mode=-1,
                                   name="s.fbx"))
    assert spaced.fps == pytest.approx(60.0) and spaced.num_frames == 4


def test_container_variants_read_alike_and_units_follow_the_file(tmp_path):
    """FBX 7.4 (32-bit records) and 7.5 (64-bit), arrays compressed or not, give one clip; the
    UnitScaleFactor (centimetres per unit) sets the clip's units unless overridden."""
    base = load_motion(_one_bone(tmp_path, keys=[0, 1, 2], values=[0, 30, 60]))
    for k, (version, compress) in enumerate([(7500, True), (7400, False), (7700, False)]):
        other = load_motion(_one_bone(tmp_path, keys=[0, 1, 2], values=[0, 30, 60], version=version,
                                      compress=compress, name=f"v{k}.fbx"))
        np.testing.assert_array_equal(other.local_rotations, base.local_rotations)
        assert f"FBX {version / 1000:.1f}, units 1 cm" in other.notes
    inches = load_motion(_one_bone(tmp_path, keys=[0, 1], values=[0, 30], unit_cm=2.54, name="in.fbx"))
    assert inches.metres_per_unit == pytest.approx(0.0254)
    assert load_motion(tmp_path / "in.fbx", metres_per_unit=0.5).metres_per_unit == 0.5


def test_root_motion_on_the_armature_and_moving_joints_are_noted(tmp_path):
    """Translation keys on the Null above the skeleton move the root (through the Null's turn and
    scale); a child joint's varying translation and animated scale are ignored with notes."""
    def extra(models):
        models.insert(0, {"name": "Armature", "kind": "Null", "parent": None, "props": [
            P("Lcl Rotation", "Lcl Rotation", "", "A", 90.0, 0.0, 0.0),
            P("Lcl Scaling", "Lcl Scaling", "", "A", 0.01, 0.01, 0.01)],
            "curves": {"Lcl Translation": np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.25]])}})
        models[1]["parent"] = 0
        models[2]["parent"] = 1
        models[2]["curves"] = {"Lcl Translation": np.array([[0.0, 10.0, 0.0], [0.0, 11.0, 0.0], [0.0, 12.0, 0.0]]),
                               "Lcl Scaling": np.array([[1.0, 1.0, 1.0], [1.2, 1.0, 1.0], [1.0, 1.0, 1.0]])}
    clip = load_motion(_one_bone(tmp_path, keys=[0, 1, 2], values=[0, 10, 20], extra=extra))
    # the hips at (0, 95, 0) cm in the armature, turned about X by 90 degrees and scaled by 0.01
    np.testing.assert_allclose(clip.root_positions, [[0, 0, 0.95], [0.5, 0, 0.95], [1.0, 0, 1.2]], atol=1e-6)
    assert "the nodes above the skeleton move: their motion is the root's" in clip.notes
    assert "translations of 1 non-root joints ignored: bone lengths are the avatar's" in clip.notes
    assert "animated scale of 1 joint ignored" in clip.notes


def test_a_second_take_is_noted_and_the_first_used(tmp_path):
    p = _one_bone(tmp_path, keys=[0, 1], values=[0, 30])
    from reconstruct.motion.fbx_binary import parse_fbx

    version, root = parse_fbx(p, p.read_bytes())
    objects = root.find("Objects")
    objects.children.append(type(objects)("AnimationStack", [777, "Run\x00\x01AnimStack", ""]))
    def to_rec(n):  # back to the test writer's records
        vals = [I32(v) if isinstance(v, int) and not isinstance(v, bool) and n.name in ("Version", "KeyVer") else v
                for v in n.values]
        return Rec(n.name, *vals, children=[to_rec(c) for c in n.children])
    q = tmp_path / "two.fbx"
    q.write_bytes(fbx_bytes([to_rec(c) for c in root.children], version=version))
    clip = load_motion(q)
    assert any(n.startswith("2 animation stacks (takes): the first ('Take 001') is used") for n in clip.notes)
    np.testing.assert_allclose(_x_angles(clip), [0, 30], atol=1e-4)


def test_broken_fbx_files_are_refused_naming_the_file(tmp_path):
    good = _one_bone(tmp_path, keys=[0, 1], values=[0, 30]).read_bytes()

    def refused(data: bytes, pattern: str, name: str = "bad.fbx"):
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(MotionFileError, match=pattern):
            load_motion(p)

    refused(good[:200], r"bad\.fbx: truncated FBX file \(it ends inside its records, at byte 200\)")
    cut = len(good) // 2
    refused(good[:cut], r"bad\.fbx: (broken FBX record at byte \d+ \(it claims to end at byte|truncated FBX file)")
    refused(good[:25], r"bad\.fbx: truncated FBX header")
    refused(b"; FBX 7.3.0 project file\nFBXHeaderExtension:  {\n}\n", r"bad\.fbx: an ASCII FBX file; only binary FBX")
    refused(good[:23] + struct.pack("<I", 6100) + good[27:], r"bad\.fbx: FBX version 6100; FBX 7\.0 or later")
    refused(b"PK\x03\x04 not an fbx", r"bad\.fbx: not a binary FBX file")
    # an array that unpacks to more than it declares (a zip bomb's shape): 4 values, 8 MB inside
    packed = zlib.compress(bytes(8 * 10 ** 6))
    raw = b"l" + struct.pack("<III", 4, 1, len(packed)) + packed
    record = struct.pack("<IIIB", 27 + 13 + 7 + len(raw), 1, len(raw), 7) + b"KeyTime" + raw
    refused(good[:27] + record + bytes(13), r"bad\.fbx: FBX record 'KeyTime': an array of 4 values holds 33 bytes, not 32")
    # no skeleton, no animation
    no_limbs = fbx_bytes(scene([{"name": "Cube", "kind": "Mesh", "parent": None}], 1, 30.0))
    refused(no_limbs, r"bad\.fbx: no skeleton in the FBX file \(no LimbNode models\)")
    still = fbx_bytes([r for r in scene([{"name": "Hips", "kind": "LimbNode", "parent": None}], 1, 30.0)])
    refused(still, r"bad\.fbx: the first animation moves none of the skeleton's joints")
    no_stack = [r for r in scene([{"name": "Hips", "kind": "LimbNode", "parent": None}], 1, 30.0)]
    no_stack[3].children = [o for o in no_stack[3].children if not o.name.startswith("Animation")]
    refused(fbx_bytes(no_stack), r"bad\.fbx: no animation in the FBX file \(only a rest pose\)")


def test_damaged_files_give_a_clip_or_a_motion_file_error(tmp_path):
    """300 copies of Blender's file, each with 1-8 random bytes changed: each reads to a clip or
    raises ``MotionFileError`` naming the file, never another exception."""
    good = (DATA / "joint_orient.fbx").read_bytes()
    rng = np.random.default_rng(5)
    p = tmp_path / "damaged.fbx"
    outcomes = {"clip": 0, "refused": 0}
    for _ in range(300):
        data = bytearray(good)
        for at in rng.integers(27, len(data), rng.integers(1, 9)):
            data[at] = int(rng.integers(0, 256))
        p.write_bytes(bytes(data))
        try:
            load_motion(p)
            outcomes["clip"] += 1
        except MotionFileError as exc:
            assert str(exc).startswith(str(p))
            outcomes["refused"] += 1
    assert outcomes["refused"] > 0 and outcomes["clip"] > 0, outcomes


def test_a_nested_record_past_its_parent_is_refused(tmp_path):
    inner = struct.pack("<IIIB", 10 ** 6, 0, 0, 1) + b"A"
    outer = struct.pack("<IIIB", 27 + 13 + 1 + len(inner) + 13, 0, 0, 1) + b"B" + inner + bytes(13)
    p = tmp_path / "bad.fbx"
    p.write_bytes(fbx_bytes([])[:27] + outer + bytes(13))
    with pytest.raises(MotionFileError, match=r"bad\.fbx: broken FBX record at byte 41"):
        load_motion(p)
