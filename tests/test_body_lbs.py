import numpy as np
import pytest
import torch

from reconstruct.body.base import vertex_normals
from reconstruct.body.lbs import apply_normals, cofactor3
from reconstruct.body.pose import BodyPose, axis_angle_to_matrix


def random_pose(body, seed=0, scale=0.35):
    rng = np.random.default_rng(seed)
    return BodyPose(rng.normal(0, scale, (body.num_joints, 3)), rng.normal(0, 0.5, 3), rng.normal(0, 0.3, 3))


def test_own_lbs_matches_anny_forward_float32(anny_body):
    pose = random_pose(anny_body)
    G = axis_angle_to_matrix(torch.tensor(pose.global_orient))
    ref = anny_body.anny_forward_vertices(pose.joint_rotations) @ G.T + torch.tensor(pose.transl)
    skin = anny_body.skinning(anny_body.skin_weights).to(dtype=torch.float32)
    ours, _ = skin(anny_body.bone_transforms(pose).float(), anny_body.canonical_vertices.float())
    err = (ours.double() - ref).abs().max().item()
    assert err <= 1e-5, f"float32 LBS differs from Anny's forward by {err:.3g} m"
    # the pose is non-trivial: vertices moved by decimetres
    assert (ref - anny_body.canonical_vertices).norm(dim=1).max() > 0.2


def test_lbs_float64_exact_and_rest_roundtrip(anny_body):
    pose = random_pose(anny_body, seed=1)
    skin = anny_body.skinning(anny_body.skin_weights)
    ours, _ = skin(anny_body.bone_transforms(pose), anny_body.canonical_vertices)
    assert (ours - anny_body.posed_vertices(pose)).abs().max() < 1e-10
    # the canonical pose maps canonical points to themselves
    same, _ = skin(anny_body.canonical_transforms, anny_body.canonical_vertices)
    assert (same - anny_body.canonical_vertices).abs().max() < 1e-10


def test_lbs_normals_agree_with_posed_mesh_normals(anny_body):
    pose = random_pose(anny_body, seed=2, scale=0.1)
    skin = anny_body.skinning(anny_body.skin_weights)
    verts, normals = skin(anny_body.bone_transforms(pose), anny_body.canonical_vertices, anny_body.canonical_normals)
    mesh_normals = vertex_normals(verts, anny_body.faces)
    cos = (normals * mesh_normals).sum(1).clamp(-1, 1)
    angles = torch.rad2deg(torch.arccos(cos))
    assert torch.allclose(normals.norm(dim=1), torch.ones(len(normals), dtype=normals.dtype))
    assert angles.median() < 2.0, angles.median()
    assert torch.quantile(angles, 0.95) < 12.0


def test_cofactor_is_inverse_transpose_times_det():
    A = torch.randn(20, 3, 3, dtype=torch.float64)
    ref = torch.linalg.det(A)[:, None, None] * torch.linalg.inv(A).transpose(1, 2)
    assert torch.allclose(cofactor3(A), ref, atol=1e-10)
    M = torch.eye(4, dtype=torch.float64).repeat(20, 1, 1)
    M[:, :3, :3] = A
    n = torch.nn.functional.normalize(torch.randn(20, 3, dtype=torch.float64), dim=1)
    out = apply_normals(M, n)
    ref_n = torch.nn.functional.normalize((torch.linalg.inv(A).transpose(1, 2) @ n[..., None])[..., 0], dim=1)
    sign = torch.sign(torch.linalg.det(A))[:, None]
    assert torch.allclose(out, sign * ref_n, atol=1e-10)


def test_axis_angle_matches_scipy_and_is_smooth_at_zero():
    from scipy.spatial.transform import Rotation

    aa = torch.randn(50, 3, dtype=torch.float64)
    assert torch.allclose(axis_angle_to_matrix(aa), torch.as_tensor(Rotation.from_rotvec(aa.numpy()).as_matrix()), atol=1e-12)
    z = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    R = axis_angle_to_matrix(z)
    R.sum().backward()
    assert torch.isfinite(z.grad).all()
    assert torch.allclose(R[0], torch.eye(3, dtype=torch.float64))


def test_canonical_pose_keeps_legs_apart(anny_body):
    j = anny_body.canonical_joints
    L = anny_body.bone_labels
    feet = (j[L.index("foot.L")] - j[L.index("foot.R")]).norm()
    hips = (j[L.index("upperleg01.L")] - j[L.index("upperleg01.R")]).norm()
    assert feet > hips + 0.1
    assert j[L.index("foot.L"), 0] > 0  # left side is +X for a body facing -Y
    # arms away from the torso (A-pose): wrists well outside the hips
    assert abs(j[L.index("wrist.L"), 0]) > abs(j[L.index("upperleg01.L"), 0]) + 0.15


def test_bad_pose_and_phenotype_are_named(anny_body):
    from reconstruct.body.anny_backend import AnnyBody

    with pytest.raises(ValueError, match=r"joint_rotations: expected shape"):
        BodyPose(np.zeros((5, 2)), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        BodyPose(np.full((anny_body.num_joints, 3), np.nan), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="expected joint rotations of shape"):
        anny_body.bone_transforms(BodyPose(np.zeros((3, 3)), np.zeros(3), np.zeros(3)))
    with pytest.raises(ValueError, match="unknown Anny phenotype keys"):
        AnnyBody({"shoe_size": 0.4})
    with pytest.raises(ValueError, match="outside"):
        AnnyBody({"age": 1.5})


def test_anny_cache_dir_respects_environment(monkeypatch, tmp_path):
    from reconstruct.body.anny_backend import anny_cache_dir

    monkeypatch.setenv("ANNY_CACHE_DIR", str(tmp_path))
    assert anny_cache_dir() == tmp_path
