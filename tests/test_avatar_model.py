import numpy as np
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
    m = AvatarModel(anny_body, AvatarConfig(gaussian_resolution=48, hidden=32))
    c = m.canonical()
    assert torch.allclose(c.means, m.base_positions)
    assert torch.allclose(c.normals, m.base_normals, atol=1e-5)
    assert torch.allclose(c.scales[:, 0], c.scales[:, 2])  # isotropic
    ratio = c.scales[:, 0].detach() / m.texel_spacing  # each Gaussian relative to its own texel spacing
    assert torch.allclose(ratio, torch.full_like(ratio, 0.6), atol=1e-5)
    assert ((c.colors > 0) & (c.colors < 1)).all()


def test_posed_gaussians_follow_the_body_lbs(anny_body):
    m = AvatarModel(anny_body, AvatarConfig(gaussian_resolution=48, hidden=32))
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
