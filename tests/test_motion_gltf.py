"""glTF 2.0 skeletal animation (reconstruct.motion.gltf): a GLB built here byte by byte from the
BVH test motion, with rest rotations that are not the identity and an armature node that turns and
scales the skeleton (centimetres to metres, as converted rigs have), reads to the BVH file's clip
(written by bvhio, an independent library) and retargets to the same poses; broken files are
refused naming the file."""

from __future__ import annotations

import base64
import json
import math
import struct

import numpy as np
import pytest
from test_motion_bvh import SKELETON, glm, quat, write_bvh

from reconstruct.motion import MotionFileError, load_motion, retarget
from reconstruct.motion.rotations import matrix_to_quat, quat_to_matrix, rotvec_to_matrix

pytestmark = pytest.mark.skipif(glm is None, reason="bvhio (pip install bvhio) writes the reference files")

NAMES = [n for n, _, _ in SKELETON]
PARENT = {n: p for n, p, _ in SKELETON}
OFFSET = {n: np.array(o, float) for n, _, o in SKELETON}


def _glm_matrix(q) -> np.ndarray:
    return quat_to_matrix(np.array([q.w, q.x, q.y, q.z]))


def _xyzw(R: np.ndarray) -> np.ndarray:
    q = matrix_to_quat(R)  # w, x, y, z
    return q[..., [1, 2, 3, 0]]


def write_glb(path, rots: dict, roots: list, *, fps: float = 30.0, seed: int = 0, as_gltf: bool = False,
              interpolation: str = "LINEAR", armature_motion: bool = False, armature_joint: bool = False):
    """The BVH test motion (``rots``: joint -> per-frame glm local quaternions, ``roots``: cm) as a
    glTF skin and animation: every joint gets a random rest rotation, and an 'Armature' node above the
    root turns it by 90 degrees about X and scales it by 0.01; the node transforms are chosen so that
    the scene's world holds the BVH skeleton in metres moving as the BVH says. With
    ``armature_motion`` the walk's translation is put on the Armature node (root motion as some
    exporters write it) instead of the root joint; with ``armature_joint`` the Armature node is a joint
    of the skin as well (an armature exported as a bone, a game rig's root bone)."""
    rng = np.random.default_rng(seed)
    T = len(roots)
    A = rotvec_to_matrix(np.array([math.pi / 2, 0.0, 0.0]))
    R0 = {n: rotvec_to_matrix(rng.normal(0.0, 0.6, 3)) for n in NAMES}  # rest world rotations
    # BVH world rotations per frame (identity rest), as glm composes them
    W = {}
    for n in NAMES:
        local = np.stack([_glm_matrix(rots[n][f]) if n in rots else np.eye(3) for f in range(T)])
        W[n] = local if PARENT[n] is None else W[PARENT[n]] @ local
    nodes = [{"name": "Armature", "rotation": _xyzw(A).tolist(), "scale": [0.01] * 3, "children": [1]}]
    index = {n: k + 1 for k, n in enumerate(NAMES)}
    blob, views, accessors = bytearray(), [], []

    def add(array: np.ndarray, kind: str) -> int:
        data = np.ascontiguousarray(array, np.float32).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        blob.extend(data + b"\0" * (-len(data) % 4))
        acc = {"bufferView": len(views) - 1, "componentType": 5126, "count": len(array), "type": kind}
        if kind == "SCALAR":
            acc.update(min=[float(array.min())], max=[float(array.max())])
        accessors.append(acc)
        return len(accessors) - 1

    times = add(np.arange(T) / fps, "SCALAR")
    samplers, channels = [], []
    for n in NAMES:
        p = PARENT[n]
        R0p = A if p is None else R0[p]
        node = {"name": n, "rotation": _xyzw(R0p.T @ R0[n]).tolist(), "translation": (R0p.T @ OFFSET[n]).tolist()}
        kids = [index[c] for c in NAMES if PARENT[c] == n]
        if kids:
            node["children"] = kids
        nodes.append(node)
        # glTF world rotation = BVH world rotation x rest world rotation; local = parent world^T world
        gw = W[n] @ R0[n]
        pw = A if p is None else W[p] @ R0[p]
        local = np.swapaxes(pw, -1, -2) @ gw if p is not None else A.T @ gw
        values = _xyzw(local)
        if interpolation == "CUBICSPLINE":
            values = np.stack([np.zeros_like(values), values, np.zeros_like(values)], 1).reshape(-1, 4)
        samplers.append({"input": times, "output": add(values, "VEC4"), "interpolation": interpolation})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": index[n], "path": "rotation"}})
    if armature_motion:  # world root = armature translation + 0.01 A (A^T rest offset)
        moves = 0.01 * (np.asarray(roots, float) - OFFSET[NAMES[0]])
        samplers.append({"input": times, "output": add(moves, "VEC3"), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": 0, "path": "translation"}})
    else:
        root_tr = (A.T @ np.asarray(roots, float).T).T
        samplers.append({"input": times, "output": add(root_tr, "VEC3"), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": index[NAMES[0]], "path": "translation"}})
    doc = {"asset": {"version": "2.0", "generator": "test_motion_gltf"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": nodes, "skins": [{"joints": [0] * armature_joint + [index[n] for n in NAMES]}],
           "animations": [{"name": "walk", "samplers": samplers, "channels": channels}],
           "buffers": [{"byteLength": len(blob)}], "bufferViews": views, "accessors": accessors}
    if as_gltf:
        doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()
        path.write_text(json.dumps(doc))
        return path
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
    return path


def _motion(T: int = 5, seed: int = 7):
    rng = np.random.default_rng(seed)
    rots = {n: [quat(rng.normal(size=3), rng.uniform(-40, 40)) for _ in range(T)] for n in NAMES}
    roots = [(rng.normal() * 20, 95 + rng.normal() * 3, rng.normal() * 20) for _ in range(T)]
    return rots, roots


@pytest.mark.parametrize("kind", ["glb", "gltf with a data uri", "cubic spline", "root motion on the armature",
                                  "root motion on an armature joint"])
def test_a_glb_reads_to_the_bvh_files_clip_and_poses(anny_body, tmp_path, kind):
    rots, roots = _motion()
    bvh = load_motion(write_bvh(tmp_path / "walk.bvh", rots, roots))
    path = tmp_path / ("walk.gltf" if kind.startswith("gltf") else "walk.glb")
    clip = load_motion(write_glb(path, rots, roots, as_gltf=kind.startswith("gltf"),
                                 interpolation="CUBICSPLINE" if kind == "cubic spline" else "LINEAR",
                                 armature_motion=kind.startswith("root motion on"),
                                 armature_joint=kind == "root motion on an armature joint"))
    assert clip.format == "gltf" and clip.num_frames == 5 and clip.fps == pytest.approx(30.0)
    if kind == "root motion on an armature joint":
        assert "'Armature' above 'Hips' read as the armature: its motion is the root's" in clip.notes
    assert clip.skeleton.names == bvh.skeleton.names
    np.testing.assert_array_equal(clip.skeleton.parents, bvh.skeleton.parents)
    np.testing.assert_allclose(clip.skeleton.offsets * 100.0, bvh.skeleton.offsets, atol=1e-4)  # m vs cm
    np.testing.assert_allclose(clip.local_rotations, bvh.local_rotations, atol=1e-5)
    np.testing.assert_allclose(clip.root_positions * 100.0, bvh.root_positions, atol=1e-3)
    np.testing.assert_allclose(clip.rest_to_body, bvh.rest_to_body)
    a, b = retarget(bvh, anny_body), retarget(clip, anny_body)
    for pa, pb in zip(a.poses, b.poses):
        np.testing.assert_allclose(pb.joint_rotations, pa.joint_rotations, atol=1e-4)
        np.testing.assert_allclose(pb.global_orient, pa.global_orient, atol=1e-4)
        np.testing.assert_allclose(pb.transl, pa.transl, atol=1e-4)


def test_broken_gltf_files_are_refused_naming_the_file(tmp_path):
    rots, roots = _motion(T=2)
    good = json.loads(write_glb(tmp_path / "a.gltf", rots, roots, as_gltf=True).read_text())

    def refused(doc_or_bytes, pattern, name="bad.gltf"):
        p = tmp_path / name
        p.write_bytes(doc_or_bytes if isinstance(doc_or_bytes, bytes) else json.dumps(doc_or_bytes).encode())
        with pytest.raises(MotionFileError, match=pattern):
            load_motion(p)

    refused(dict(good, skins=[]), r"bad\.gltf: no skin")
    refused(dict(good, animations=[]), r"bad\.gltf: no animation in the file")
    outside = json.loads(json.dumps(good))
    outside["buffers"][0]["uri"] = "../secret.bin"
    refused(outside, r"bad\.gltf: buffer 0 points outside the file's folder")
    remote = json.loads(json.dumps(good))
    remote["buffers"][0]["uri"] = "https://example.com/x.bin"
    refused(remote, r"points outside the file's folder")
    short = json.loads(json.dumps(good))
    short["accessors"][1]["count"] = 10 ** 6
    refused(short, r"bad\.gltf: accessor 1 reaches past the end of its buffer")
    refused(dict(good, asset={"version": "1.0"}), r"not a glTF 2\.0 file")
    refused(b"glTF" + struct.pack("<II", 1, 20) + bytes(8), r"bad\.glb: GLB version 1", name="bad.glb")
    refused(b"glTF" + struct.pack("<II", 2, 20) + bytes(8), r"bad\.glb: GLB without a JSON chunk", name="bad.glb")
    refused(b"glTF\x02\x00", r"bad\.glb: truncated GLB header", name="bad.glb")
    refused(b"\x00\x01 not json", r"bad\.gltf: not a glTF file")
