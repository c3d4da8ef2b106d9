"""Extreme bodies, poses and cameras through the avatar: LBS, rendering and the Stage I loss.

Expectation for every case: the posed Gaussians, the loss and every parameter gradient finite;
normals unit length (|1 - |n|| < 1e-4); the gradient norm of the Stage I loss within GRAD_RATIO
(25x) of that of the rest pose seen by the ordinary camera: bounded, no spike from the extreme
itself. (A camera inside the body comes closest, ~15x: screen-space derivatives grow as 1/depth.)
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from stability_helpers import all_finite, grad_norm, record, stage1_loss

from reconstruct.body.pose import BodyPose
from reconstruct.camera import Camera

GRAD_RATIO = 25.0
SIZE = 48


def body_camera(body, *, distance=3.5, fov=40.0, azimuth=0.0, size=SIZE) -> Camera:
    z = body.canonical_vertices[:, 2]
    target = (0.0, 0.0, float(0.5 * (z.min() + z.max())))
    return Camera.orbit(azimuth, 0.0, distance, target, width=size, height=size, fov_y_deg=fov)


def loss_and_grads(model, transforms, cam):
    model.zero_grad(set_to_none=True)
    target = torch.full((cam.height, cam.width, 3), 0.5)
    normal = torch.zeros(cam.height, cam.width, 3)
    loss, _, r = stage1_loss(model, transforms, cam, target, normal)
    loss.backward()
    params = list(model.parameters())
    return loss, r, params


def check(name, model, body, pose: BodyPose, cam, reference_norm=None):
    transforms = body.bone_transforms(pose).float()
    rot = transforms[:, :3, :3].double()
    assert all_finite([transforms]), f"{name}: non-finite bone transforms"
    assert torch.allclose(torch.linalg.det(rot), torch.ones(len(rot), dtype=torch.float64), atol=1e-4)
    with torch.no_grad():
        posed = model.pose(model.canonical(), transforms)
    assert all_finite([posed.means, posed.normals]), f"{name}: non-finite posed Gaussians"
    unit_err = float((posed.normals.norm(dim=1) - 1).abs().max())
    assert unit_err < 1e-4, f"{name}: normals off unit length by {unit_err:.2g}"
    loss, r, params = loss_and_grads(model, transforms, cam)
    assert all_finite([loss, r.rgb, r.normal, r.depth]), f"{name}: non-finite loss or render"
    assert all_finite([p.grad for p in params]), f"{name}: non-finite gradient"
    gn = grad_norm(params)
    det_min = float(torch.linalg.det(model.lbs_matrices(transforms)[:, :3, :3]).min())
    figures = dict(loss=float(loss.detach()), grad_norm=gn, normal_unit_err=unit_err, lbs_det_min=det_min,
                   coverage=float(r.alpha.detach().mean()))
    if reference_norm is not None:
        figures["grad_ratio"] = gn / reference_norm
        assert gn <= GRAD_RATIO * reference_norm, f"{name}: gradient norm {gn:.3g} vs {reference_norm:.3g} at rest"
    record(name, **figures)
    return gn


@pytest.fixture(scope="module")
def rest_norm(tiny_avatar, anny_body):
    pose = anny_body.canonical_pose()
    transforms = anny_body.bone_transforms(pose).float()
    _, _, params = loss_and_grads(tiny_avatar, transforms, body_camera(anny_body))
    return grad_norm(params)


def _pose(body, global_orient=(0.0, 0.0, 0.0), **rotations) -> BodyPose:
    r = body.canonical_joint_rotations().copy()
    for bone, v in rotations.items():
        r[body.bone_labels.index(bone.replace("_", "."))] = v
    return BodyPose(r, np.asarray(global_orient, float), np.zeros(3))


POSES = {
    # the upper arms swing 126 deg forward and across, the forearms 86 deg further: through the torso
    "arms crossed through the torso": dict(upperarm01_L=[0, 0, -2.2], upperarm01_R=[0, 0, 2.2],
                                           lowerarm01_L=[0, 0, -1.5], lowerarm01_R=[0, 0, 1.5]),
    "deep squat (hips 115 deg, knees 150 deg)": dict(upperleg01_L=[-2.0, 0, 0], upperleg01_R=[-2.0, 0, 0],
                                                     lowerleg01_L=[2.6, 0, 0], lowerleg01_R=[2.6, 0, 0]),
    "180 deg turn (global orientation pi)": dict(global_orient=(0.0, 0.0, math.pi)),
    "hyper-extended knees, elbows, neck": dict(lowerleg01_L=[-1.2, 0, 0], lowerleg01_R=[-1.2, 0, 0],
                                               lowerarm01_L=[0, 0, 1.5], lowerarm01_R=[0, 0, -1.5],
                                               neck01=[1.5, 0, 0]),
    "179.9 deg twists (forearm, thigh, neck)": dict(lowerarm01_L=[math.pi * 0.9995, 0, 0],
                                                    upperleg02_R=[0, 0, math.pi * 0.9995],
                                                    neck02=[0, math.pi * 0.9995, 0]),
}


@pytest.mark.parametrize("name", list(POSES))
def test_extreme_poses(name, tiny_avatar, anny_body, rest_norm):
    kw = dict(POSES[name])
    pose = _pose(anny_body, kw.pop("global_orient", (0.0, 0.0, 0.0)), **kw)
    check(f"pose: {name}", tiny_avatar, anny_body, pose, body_camera(anny_body), rest_norm)


PHENOTYPES = {
    "infant (age 0)": {"age": 0.0},
    "elder (age 1)": {"age": 1.0},
    "very heavy (weight 1, muscle 1)": {"weight": 1.0, "muscle": 1.0},
    "very tall (height 1)": {"height": 1.0},
    "every phenotype at 0": dict.fromkeys(("gender", "age", "muscle", "weight", "height", "proportions"), 0.0),
    "every phenotype at 1": dict.fromkeys(("gender", "age", "muscle", "weight", "height", "proportions"), 1.0),
}


@pytest.mark.parametrize("name", list(PHENOTYPES))
def test_extreme_body_shapes(name, tiny_avatar_config, anny_body, rest_norm):
    from reconstruct.avatar.model import AvatarModel
    from reconstruct.body.anny_backend import AnnyBody

    body = AnnyBody(PHENOTYPES[name], leg_spread_deg=5.0)
    assert all_finite([body.rest_vertices, body.canonical_vertices])
    assert 0.4 < body.height < 2.5, f"{name}: implausible height {body.height:.2f} m"
    torch.manual_seed(0)
    model = AvatarModel(body, tiny_avatar_config)
    assert all_finite([model.base_positions, model.base_normals, model.canonical_inverse, model.texel_spacing])
    assert float(model.texel_spacing.min()) > 0
    # a walking-like pose, framed like the default body (the camera distance follows the height)
    pose = _pose(body, upperleg01_L=[-0.5, 0, 0], upperleg01_R=[0.4, 0, 0], lowerleg01_L=[0.6, 0, 0])
    cam = body_camera(body, distance=3.5 * body.height / anny_body.height)
    check(f"body: {name} ({body.height:.2f} m)", model, body, pose, cam, rest_norm)


CAMERAS = {
    "very wide field of view (170 deg)": dict(fov=170.0, distance=0.6),
    "very narrow field of view (0.5 deg)": dict(fov=0.5, distance=400.0),
    "body far larger than the frame (0.4 m away)": dict(distance=0.4),
    "camera inside the body (0.05 m from the centre)": dict(distance=0.05),
    "body far smaller than the frame (300 m, ~0.3 px)": dict(distance=300.0),
}


@pytest.mark.parametrize("name", list(CAMERAS))
def test_extreme_cameras(name, tiny_avatar, anny_body, rest_norm):
    cam = body_camera(anny_body, **CAMERAS[name])
    check(f"camera: {name}", tiny_avatar, anny_body, anny_body.canonical_pose(), cam, rest_norm)
