"""EWA projection: against gsplat's pure-torch projection, culling, boxes and gradients."""

from __future__ import annotations

import math

import pytest
import torch

from reconstruct.camera import Camera
from reconstruct.raster.projection import covariance_3d, pixel_boxes, project_gaussians, quat_to_rotmat

F64 = torch.float64


def off_centre_camera(width: int = 64, height: int = 48) -> Camera:
    cam = Camera.look_at((0.4, -2.5, 0.3), (0.0, 0.0, 0.0), width=width, height=height, fov_y_deg=40)
    K = cam.K.copy()
    K[0, 2] += 0.13 * width
    K[1, 2] -= 0.09 * height
    return Camera(K, cam.R, cam.t, width, height)


def scene(n: int, seed: int, spread: float = 1.2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Gaussians around the origin, some well outside the field of view (clamped Jacobian)."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=F64) - 0.5) * 2 * spread
    quats = torch.randn(n, 4, generator=g, dtype=F64)
    scales = torch.rand(n, 3, generator=g, dtype=F64) * 0.08 + 0.005
    return means, quats, scales


def with_large_off_view(cam: Camera, means, quats, scales):
    """Appends big Gaussians centred left of and below the view (their x/z or y/z is clamped in the
    Jacobian) whose boxes still reach into the image."""
    z = torch.linspace(2.0, 3.0, 8, dtype=F64)
    u = -(cam.cx / cam.fx) - 0.35 + 0.02 * torch.arange(8, dtype=F64)
    v = (cam.height - cam.cy) / cam.fy + 0.3 + 0.02 * torch.arange(8, dtype=F64)
    p_cam = torch.stack([u * z, (v * z).flip(0), z], dim=-1)
    world = (p_cam - torch.tensor(cam.t)) @ torch.tensor(cam.R)
    big = torch.full((8, 3), 0.35, dtype=F64)
    return (torch.cat([means, world]), torch.cat([quats, torch.randn(8, 4, dtype=F64)]), torch.cat([scales, big]))


def camera_tensors(cam: Camera, dtype=F64):
    return tuple(torch.tensor(a, dtype=dtype) for a in (cam.R, cam.t, cam.K))


def project(cam: Camera, means, quats, scales, dtype=F64, **kwargs):
    return project_gaussians(means.to(dtype), quats.to(dtype), scales.to(dtype), *camera_tensors(cam, dtype),
                             cam.width, cam.height, **kwargs)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_matches_gsplat_torch_projection(dtype):
    pytest.importorskip("packaging")
    torch_impl = pytest.importorskip("gsplat.cuda._torch_impl")
    cam = off_centre_camera()
    means, quats, scales = (x.to(dtype) for x in with_large_off_view(cam, *scene(400, seed=0)))
    ours = project(cam, means, quats, scales, dtype)
    covars, _ = torch_impl._quat_scale_to_covar_preci(quats, scales, compute_preci=False)
    viewmat = torch.tensor(cam.viewmat, dtype=dtype)
    K = torch.tensor(cam.K, dtype=dtype)
    radii, means2d, depths, conics, _ = torch_impl._fully_fused_projection(
        means, covars, viewmat[None], K[None], cam.width, cam.height, eps2d=0.3, near_plane=cam.near)
    both = (ours.radii > 0) & (radii[0] > 0).all(dim=-1)
    assert both.sum() > 150
    clamped = (ours.means2d[:, 0] < -0.2 * cam.width) | (ours.means2d[:, 1] > 1.2 * cam.height)
    assert (both & clamped).any(), "some compared Gaussians must lie in the clamped zone"
    errors = {
        "means2d (px)": float((ours.means2d[both] - means2d[0][both]).abs().max()),
        "conics (rel)": float((ours.conics[both] - conics[0][both]).abs().max() / conics[0][both].abs().max()),
        "depths (m)": float((ours.depths[both] - depths[0][both]).abs().max()),
        "cov3d": float((covariance_3d(quats, scales) - covars).abs().max()),
    }
    print(f"projection vs gsplat _torch_impl ({dtype}):", {k: f"{v:.1e}" for k, v in errors.items()})
    tolerance = 1e-10 if dtype == torch.float64 else 1e-4
    assert all(v < tolerance for v in errors.values()), errors


def test_rotation_matrices_match_gsplat_and_are_rotations():
    torch_impl = pytest.importorskip("gsplat.cuda._torch_impl")
    quats = torch.randn(50, 4, dtype=F64) * 3
    R = quat_to_rotmat(quats)
    assert torch.allclose(R, torch_impl._quat_to_rotmat(quats), atol=1e-14)
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3, dtype=F64).expand(50, 3, 3), atol=1e-14)
    assert torch.allclose(torch.linalg.det(R), torch.ones(50, dtype=F64))


def test_zero_quaternion_is_the_identity():
    quats = torch.zeros(2, 4, dtype=F64, requires_grad=True)
    R = quat_to_rotmat(quats)
    assert torch.equal(R.detach(), torch.eye(3, dtype=F64).expand(2, 3, 3))
    R.sum().backward()
    assert torch.isfinite(quats.grad).all()


def test_radius_and_box():
    """radius = ceil(3 sqrt(largest eigenvalue of cov2d + 0.3 I)); the box holds exactly the pixel
    centres within radius of the mean along both axes (clipped to the image)."""
    cam = off_centre_camera()
    means, quats, scales = scene(300, seed=2, spread=0.6)
    p = project(cam, means, quats, scales)
    a, b, c = p.conics.unbind(-1)
    det = a * c - b * b
    cov = torch.stack([c / det, -b / det, -b / det, a / det], -1).reshape(-1, 2, 2)  # inverse of the conic
    want = torch.ceil(3 * torch.sqrt(torch.linalg.eigvalsh(cov)[:, -1]))
    shown = p.radii > 0
    assert shown.sum() > 100
    assert torch.equal(p.radii[shown].double(), want[shown])
    cols = torch.arange(cam.width, dtype=F64) + 0.5
    rows = torch.arange(cam.height, dtype=F64) + 0.5
    for g in torch.nonzero(shown).squeeze(1)[:40]:
        r = float(p.radii[g])
        inside_x = torch.nonzero((cols - p.means2d[g, 0]).abs() <= r).squeeze(1)
        inside_y = torch.nonzero((rows - p.means2d[g, 1]).abs() <= r).squeeze(1)
        assert p.boxes[g].tolist() == [inside_x[0], inside_x[-1], inside_y[0], inside_y[-1]]


def test_culling():
    cam = Camera.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), width=32, height=32, fov_y_deg=40)
    means = torch.tensor([[0.0, 0.0, 0.0],     # in view
                          [0.0, -3.0, 0.0],    # at the camera centre (depth 0)
                          [0.0, -6.0, 0.0],    # behind the camera
                          [50.0, 0.0, 0.0],    # far outside the image
                          [0.0, -2.995, 0.0]],  # in front of the camera but nearer than near=0.01
                         dtype=F64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 5, dtype=F64)
    scales = torch.full((5, 3), 0.02, dtype=F64)
    p = project(cam, means, quats, scales)
    assert p.radii.tolist()[0] > 0 and p.radii.tolist()[1:] == [0, 0, 0, 0]
    assert (p.boxes[1:, 0] > p.boxes[1:, 1]).all()
    assert torch.isfinite(p.means2d).all() and torch.isfinite(p.conics).all()
    # a custom near plane
    assert project(cam, means, quats, scales, near=3.5).radii[0] == 0


def test_pixel_boxes_clip_to_the_image():
    means2d = torch.tensor([[-3.0, 5.0], [10.0, 40.0], [31.9, 0.1]], dtype=F64)
    radii = torch.tensor([4, 2, 3], dtype=torch.int32)
    boxes = pixel_boxes(means2d, radii, 32, 24)
    # the second one lies below the image: its row range is empty
    assert boxes.tolist() == [[0, 0, 1, 8], [8, 11, 24, 23], [29, 31, 0, 2]]
    assert pixel_boxes(means2d, torch.zeros(3, dtype=torch.int32), 32, 24).tolist() == [[0, -1, 0, -1]] * 3


def test_projection_gradcheck():
    cam = off_centre_camera(40, 30)
    means, quats, scales = scene(6, seed=4, spread=0.5)
    R, t, K = camera_tensors(cam)

    def run(m, q, s):
        p = project_gaussians(m, q, s, R, t, K, cam.width, cam.height)
        return p.means2d, p.conics, p.depths

    inputs = [x.clone().requires_grad_() for x in (means, quats, scales)]
    assert torch.autograd.gradcheck(run, inputs, eps=1e-6, atol=1e-7, rtol=1e-6)


def test_float32_close_to_float64():
    cam = off_centre_camera()
    means, quats, scales = scene(200, seed=5)
    p64, p32 = project(cam, means, quats, scales), project(cam, means, quats, scales, torch.float32)
    shown = p64.radii > 0
    assert float((p32.means2d.double() - p64.means2d)[shown].abs().max()) < 1e-3
    rel = (p32.conics.double() - p64.conics)[shown].abs().max() / p64.conics[shown].abs().max()
    assert float(rel) < 1e-5
    assert math.isclose(float(p32.depths.double().sum()), float(p64.depths.sum()), rel_tol=1e-6)
