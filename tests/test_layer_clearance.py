"""A garment layer kept outside the posed body (reconstruct.avatar.layer_clearance): the push
against a float64 brute-force reference, its gradient, and the model's posing with it (only
the Gaussians inside the body move, by exactly what they lack; canonical and clear poses are
untouched; subsets pose like the whole; old records load without it)."""

import numpy as np
import pytest
import torch

from reconstruct.avatar import AvatarConfig, AvatarModel
from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, landmark_heights
from reconstruct.avatar.layer_clearance import COVERED_PARTS, covered_ids, push_out
from reconstruct.body.parts import PART_INDEX
from reconstruct.body.pose import BodyPose
from reconstruct.body.lbs import apply_normals, apply_points

CLEAR = 0.005


def _reference(p, s, n, clearance):
    """float64, brute force: each point moved along the normal of its nearest surface point."""
    p, s, n = (np.asarray(a, np.float64) for a in (p, s, n))
    j = np.linalg.norm(p[:, None] - s[None], axis=2).argmin(1)
    depth = ((p - s[j]) * n[j]).sum(1)
    return p + np.maximum(clearance - depth, 0)[:, None] * n[j]


def test_push_out_matches_brute_force_on_a_sphere():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    n = d / np.linalg.norm(d, axis=1, keepdims=True)
    s = 0.1 * n  # a sphere of 10 cm, outward normals
    q = rng.normal(size=(300, 3))
    p = q / np.linalg.norm(q, axis=1, keepdims=True) * rng.uniform(0.05, 0.13, (300, 1))
    out = push_out(torch.as_tensor(p, dtype=torch.float32), torch.as_tensor(s, dtype=torch.float32),
                   torch.as_tensor(n, dtype=torch.float32), CLEAR).double().numpy()
    ref = _reference(p.astype(np.float32), s.astype(np.float32), n.astype(np.float32), CLEAR)
    np.testing.assert_allclose(out, ref, atol=1e-6)
    r = np.linalg.norm(p, axis=1)
    inside = r < 0.1
    assert inside.sum() > 50 and (~inside).sum() > 50
    # those inside end (about) the clearance outside the sphere; those well outside do not move
    assert np.abs(np.linalg.norm(out[inside], axis=1) - (0.1 + CLEAR)).max() < 3e-3
    far = r > 0.1 + 2 * CLEAR
    assert np.array_equal(out[far], p[far].astype(np.float32))


def test_push_out_passes_the_gradient_unchanged():
    s = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    p = torch.tensor([[0.1, 0.0, -0.02], [0.9, 0.0, 0.3]], requires_grad=True)
    out = push_out(p, s, n, CLEAR)
    assert torch.allclose(out.detach(), torch.tensor([[0.1, 0.0, CLEAR], [0.9, 0.0, 0.3]]))
    w = torch.arange(6.0).reshape(2, 3)
    (out * w).sum().backward()
    assert torch.equal(p.grad, w)


@pytest.fixture(scope="module")
def body(tiny_scene):
    return tiny_scene.body_model()


def _model(body, clearance=CLEAR):
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)
    # a coarse grid, with the weight filter of 3 rows and 6 columns it was measured with
    layer = build_garment_layer(body, hint, cols=16, row_step=0.06, diffusion=(3.0, 6.0))
    cfg = AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                       hidden=32, garment_clearance=clearance)
    torch.manual_seed(0)
    return AvatarModel(body, cfg, layer=layer)


def _strided_pose(body):
    """Legs apart and turned: the thighs come out through cloth skinned with a blend."""
    rng = np.random.default_rng(1)
    return BodyPose(rng.normal(0, 0.35, (body.num_joints, 3)), np.zeros(3), np.zeros(3))


def test_model_pushes_only_the_layer_inside_the_body(body):
    m, bare = _model(body), _model(body, clearance=0.0)
    N = m.num_body
    T = body.bone_transforms(_strided_pose(body)).float()
    with torch.no_grad():
        c = m.canonical()
        posed, ref = m.pose(c, T), bare.pose(c, T)
        M = bare.lbs_matrices(T)
    assert torch.equal(posed.means[:N], ref.means[:N]) and torch.equal(posed.normals, ref.normals)
    ids = covered_ids(m.parts()[:N])
    assert set(np.unique(m.parts()[ids])) == {PART_INDEX[p] for p in COVERED_PARTS}
    s = apply_points(M[ids], m.base_positions[ids]).double().numpy()
    n = apply_normals(M[ids], m.base_normals[ids]).double().numpy()
    expect = _reference(ref.means[N:].double().numpy(), s, n, CLEAR)
    np.testing.assert_allclose(posed.means[N:].double().numpy(), expect, atol=1e-5)
    moved = np.linalg.norm(expect - ref.means[N:].double().numpy(), axis=1) > 0
    assert moved.sum() > 0 and (~moved).sum() > 0  # the case is real: the pose pokes through the layer
    # in the canonical pose the layer is built clear of the body: next to nothing moves (the
    # coarse 48-texel body's normals tilt at the waist), far less than in the strided pose
    Tc = body.canonical_transforms.float()
    with torch.no_grad():
        still = (m.pose(c, Tc).means[N:] - bare.pose(c, Tc).means[N:]).norm(dim=1) == 0
    assert (~still).sum() < 0.2 * moved.sum()


def test_subsets_pose_like_the_whole_and_need_the_clearance_matrices(body):
    m = _model(body)
    N = m.num_body
    T = body.bone_transforms(_strided_pose(body)).float()
    idx = torch.tensor([N + 5, 3, N, N + m.num_layer - 1, 11])
    with torch.no_grad():
        whole = m.pose(m.canonical(), T)
        M = m.lbs_matrices(T)
        sub = m.pose_with(m.canonical(index=idx), M[idx], m.clearance_matrices(M), m.layer_stretch_of(M))
        assert torch.allclose(sub.means, whole.means[idx], atol=1e-6)
        assert torch.allclose(sub.scales, whole.scales[idx], atol=1e-6)
        posed = m.pose(m.canonical(index=idx), T)
        assert torch.allclose(posed.means, whole.means[idx], atol=1e-6)
        assert torch.allclose(posed.scales, whole.scales[idx], atol=1e-6)
        with pytest.raises(ValueError, match="clearance matrices"):
            m.pose_with(m.canonical(index=idx), M[idx])
        # a subset of body Gaussians only needs none
        body_only = torch.tensor([1, 2, 3])
        assert torch.allclose(m.pose_with(m.canonical(index=body_only), M[body_only]).means, whole.means[body_only])


def test_setting_defaults_and_old_records():
    from reconstruct.train.config import Stage1Config

    assert AvatarConfig().garment_clearance == CLEAR
    old = Stage1Config().to_dict()
    del old["avatar"]["garment_clearance"]
    assert Stage1Config.from_dict(old).avatar.garment_clearance == 0.0
