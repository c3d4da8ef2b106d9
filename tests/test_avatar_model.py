import numpy as np
import pytest
import torch

from reconstruct.avatar import AvatarConfig, AvatarModel
from reconstruct.body.pose import BodyPose


def test_default_decoder_matches_paper_size_and_stage2_width(anny_body):
    m = AvatarModel(anny_body, AvatarConfig(gaussian_resolution=32))
    params = sum(p.numel() for p in m.decoder.parameters())
    assert 150_000 < params < 220_000  # the paper: ~186K decoder parameters
    assert m.decoder.trunk[0].in_features == 2 * 64 + 2  # [S, S] (Stage I) == [S, P] (Stage II) + uv
    assert tuple(m.features.shape) == (1, 64, 128, 128)


def test_initial_gaussians_sit_on_the_body(anny_body):
    m = AvatarModel(anny_body, AvatarConfig.paper(gaussian_resolution=48, hidden=32))
    c = m.canonical()
    assert torch.allclose(c.means, m.base_positions)
    assert torch.allclose(c.normals, m.base_normals, atol=1e-5)
    assert torch.allclose(c.scales[:, 0], c.scales[:, 2])  # isotropic
    ratio = c.scales[:, 0].detach() / m.texel_spacing  # each Gaussian relative to its own texel spacing
    assert torch.allclose(ratio, torch.full_like(ratio, 0.6), atol=1e-5)
    assert ((c.colors > 0) & (c.colors < 1)).all()


@pytest.mark.parametrize("config", [AvatarConfig.paper(gaussian_resolution=48, hidden=32),
                                    AvatarConfig(gaussian_resolution=48, decode_resolution=24, hidden=32)])
def test_posed_gaussians_follow_the_body_lbs(anny_body, config):
    m = AvatarModel(anny_body, config)
    rng = np.random.default_rng(0)
    pose = BodyPose(rng.normal(0, 0.2, (anny_body.num_joints, 3)), np.array([0, 0, 0.3]), np.array([0.1, 0, 0]))
    T = anny_body.bone_transforms(pose)
    posed = m.pose(m.canonical(), T.float())
    skin = anny_body.skinning(m.uv_map.weights)  # independent float64 path
    ref, ref_n = skin(T, m.uv_map.positions, m.uv_map.normals)
    assert (posed.means.double() - ref).abs().max() < 1e-4
    assert (posed.normals.double() - ref_n).abs().max() < 1e-3


def test_gradients_reach_features_and_decoder(anny_body):
    m = AvatarModel(anny_body, AvatarConfig(gaussian_resolution=32, hidden=16, feature_channels=8, pose_feature_channels=8))
    c = m.canonical()
    (c.colors.sum() + c.means.sum() + c.scales.sum() + (c.normals * torch.tensor([0.3, -0.5, 0.8])).sum()).backward()
    assert m.features.grad is not None and m.features.grad.abs().sum() > 0
    assert all(p.grad is not None for p in m.decoder.parameters())


# ----- discs in the tangent frame, coarse decoding, decoding a subset ------------------------------

def _quat_to_matrix64(q: torch.Tensor) -> torch.Tensor:
    """Independent float64 reference: the rotation of unit (w, x, y, z) quaternions."""
    q = q.double() / q.double().norm(dim=1, keepdim=True)
    w, x, y, z = q.unbind(1)
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1)], 1)


def test_frame_quaternions_rotate_z_onto_the_normal():
    from reconstruct.avatar.model import frame_quaternions

    g = torch.Generator().manual_seed(0)
    n = torch.nn.functional.normalize(torch.randn(2000, 3, generator=g, dtype=torch.float64), dim=1)
    t = torch.randn(2000, 3, generator=g, dtype=torch.float64)
    # the hard cases: each branch of the conversion, normals along and against every axis
    axes = torch.cat([torch.eye(3), -torch.eye(3)]).double()
    n = torch.cat([n, axes, axes])
    t = torch.cat([t, axes.roll(1, 1), -axes.roll(2, 1)])
    R = _quat_to_matrix64(frame_quaternions(t, n))
    tt = t - (t * n).sum(1, keepdim=True) * n
    tt = tt / tt.norm(dim=1, keepdim=True)
    assert (R[:, :, 2] - n).abs().max() < 1e-12
    assert (R[:, :, 0] - tt).abs().max() < 1e-8
    assert (torch.linalg.det(R) - 1).abs().max() < 1e-12
    # smooth where it is used: the gradient matches finite differences
    sub_t = t[:16].clone()
    assert torch.autograd.gradcheck(lambda a: frame_quaternions(sub_t, torch.nn.functional.normalize(a, dim=1)),
                                    (n[:16].clone().requires_grad_(),))


def test_discs_lie_in_the_posed_tangent_plane_and_neighbours_overlap(anny_body):
    from reconstruct.body.lbs import apply_normals
    from reconstruct.body.uv_map import texel_neighbours

    cfg = AvatarConfig(gaussian_resolution=64, decode_resolution=32, hidden=32)
    m = AvatarModel(anny_body, cfg)
    c = m.canonical()
    # initial size: init_scale_factor x the texel step along u and v, thin along the normal
    assert torch.allclose(c.scales[:, :2], cfg.init_scale_factor * m.texel_steps, rtol=1e-4)
    assert torch.allclose(c.scales[:, 2], cfg.disc_thickness * c.scales[:, :2].min(1).values, rtol=1e-5)
    # the floor: with the scale head driven to its minimum, a disc still reaches half way to its
    # u / v neighbours at more than 1/3 of its peak (neighbours overlap)
    with torch.no_grad():
        m.decoder.heads["scale"][-1].bias.fill_(-30.0)
    low = m.canonical()
    assert torch.allclose(low.scales[:, :2], cfg.scale_floor * m.texel_steps, rtol=1e-4)
    nb = torch.as_tensor(texel_neighbours(m.uv_map.texel_rc, 64))
    ok = nb[:, 0] >= 0
    gap = (m.base_positions[nb[ok, 0]] - m.base_positions[ok]).norm(dim=1)
    typical = gap < 2 * m.texel_steps[ok, 0]  # not across an atlas seam
    assert (torch.exp(-0.5 * (0.5 * gap[typical] / low.scales[ok][typical, 0]) ** 2) > 1 / 3).float().mean() > 0.95
    # posed: the disc's normal axis is the LBS normal, its first axis the LBS image of the tangent
    rng = np.random.default_rng(1)
    pose = BodyPose(rng.normal(0, 0.3, (anny_body.num_joints, 3)), np.array([0.2, 0, 0.5]), np.zeros(3))
    T = anny_body.bone_transforms(pose)
    posed = m.pose(c, T.float())
    R = _quat_to_matrix64(posed.quats)
    skin = anny_body.skinning(m.uv_map.weights)  # float64 path
    M = skin.matrices(T)
    n_ref = apply_normals(M, m.uv_map.normals)
    assert (R[:, :, 2] - n_ref).abs().max() < 1e-3
    t_ref = (M[:, :3, :3] @ m.base_tangents.double()[..., None])[..., 0]
    t_ref = t_ref - (t_ref * n_ref).sum(1, keepdim=True) * n_ref
    t_ref = t_ref / t_ref.norm(dim=1, keepdim=True)
    assert (R[:, :, 0] - t_ref).abs().max() < 1e-3


def test_coarse_decoding_interpolates_bilinearly(anny_body):
    """Decoded at a coarser grid, each Gaussian gets the bilinear blend of its four nodes: an output
    that is affine in UV comes out at the Gaussian's own UV (away from the grid's outer border)."""
    m = AvatarModel(anny_body, AvatarConfig(gaussian_resolution=64, decode_resolution=16, hidden=16,
                                            feature_channels=8, pose_feature_channels=8))
    assert m.num_nodes < m.num_gaussians

    class Affine(torch.nn.Module):
        def forward(self, x):
            uv = x[:, -2:]
            a = torch.cat([uv, 3 * uv[:, :1] - uv[:, 1:]], 1)
            return {"offset": a, "normal_offset": a, "color": a, "scale": a[:, :1]}

    m.decoder = Affine()
    out = m.decode_raw()
    g = m.uv_grid.double()
    inside = (g.abs() < 1 - 2 / 16).all(1)
    want = torch.cat([g, 3 * g[:, :1] - g[:, 1:]], 1)
    assert (out["offset"].double()[inside] - want[inside]).abs().max() < 1e-5
    assert torch.allclose(m.node_weights.sum(1), torch.ones(m.num_gaussians))


@pytest.mark.parametrize("decode_resolution", [None, 24])
def test_decoding_a_subset_equals_decoding_all(anny_body, decode_resolution):
    m = AvatarModel(anny_body, AvatarConfig(gaussian_resolution=48, decode_resolution=decode_resolution, hidden=16,
                                            feature_channels=8, pose_feature_channels=8))
    with torch.no_grad():
        for p in m.decoder.parameters():
            p.add_(0.05 * torch.randn_like(p))
    full = m.canonical()
    idx = torch.arange(0, m.num_gaussians, 3)
    part = m.canonical(index=idx)
    for name in ("means", "normals", "colors", "scales", "offsets_raw", "tangents"):
        assert torch.allclose(getattr(part, name), getattr(full, name)[idx], atol=1e-6), name
    T = anny_body.canonical_transforms.float()
    pf, pp = m.pose(full, T), m.pose(part, T)
    assert torch.allclose(pp.means, pf.means[idx], atol=1e-6) and torch.allclose(pp.quats, pf.quats[idx], atol=1e-6)


def test_facing_keeps_the_side_towards_the_camera(anny_body):
    m = AvatarModel(anny_body, AvatarConfig(gaussian_resolution=48, hidden=16, feature_channels=8,
                                            pose_feature_channels=8))
    M = m.lbs_matrices(anny_body.canonical_transforms.float())
    front = m.facing(M, np.array([0.0, -3.0, 1.0]), 0.25)  # the avatar faces -Y
    n = m.base_normals[front]
    assert 0.4 < len(front) / m.num_gaussians < 0.75
    assert (n[:, 1] < 0.5).all()  # nothing that points straight away (+Y)
    assert set(torch.nonzero(m.base_normals[:, 1] < -0.5)[:, 0].tolist()) <= set(front.tolist())
