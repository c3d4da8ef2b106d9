"""The garment layer's cover prior (train/layer_cover.py): mean (1 - opacity) over the layer
Gaussians of a view that project inside its mask. The projection is checked against the camera's
own float64 NumPy projection; the term against its formula; in a training step it raises the
opacity of the layer inside the silhouette and leaves the rest to the alpha loss."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, landmark_heights
from reconstruct.camera import Camera
from reconstruct.train.config import Stage1Config
from reconstruct.train.evaluate import inner_mask
from reconstruct.train.layer_cover import inside_mask, layer_cover_term


def _camera() -> Camera:
    return Camera.look_at(eye=(0.3, 0.2, 3.0), target=(0.0, 0.0, 0.0), width=40, height=30, fov_y_deg=40.0)


def _inner(mask, inset: int) -> torch.Tensor:
    """The (H,W) mask eroded as training erodes it (``evaluate.inner_mask``)."""
    return inner_mask(torch.as_tensor(mask, dtype=torch.float32) > 0.5, inset)


def _reference_inside(points: np.ndarray, cam: Camera, mask: np.ndarray, inset: int) -> np.ndarray:
    """Float64: project with Camera.project, floor to the pixel, test that every pixel within
    ``inset`` (Chebyshev) is in the mask, pixels off the image counting as in it (the image border
    is not background, as evaluate.inner_mask)."""
    uv, z = cam.project(points)
    H, W = mask.shape
    out = np.zeros(len(points), bool)
    for k, ((u, v), d) in enumerate(zip(uv, z)):
        if not d > 1e-6:
            continue
        c, r = int(np.floor(u)), int(np.floor(v))
        if not (0 <= c < W and 0 <= r < H):
            continue
        win = mask[max(0, r - inset):r + inset + 1, max(0, c - inset):c + inset + 1]
        out[k] = bool(win.all())
    return out


@pytest.mark.parametrize("inset", [0, 1, 2])
def test_inside_mask_against_the_cameras_projection(inset):
    cam = _camera()
    rng = np.random.default_rng(3)
    mask = np.zeros((30, 40), bool)
    mask[5:26, 8:30] = True
    mask[12:16, 15:20] = False  # a hole in the middle
    mask[0:8, 35:40] = True  # touching the image border
    pts = rng.uniform(-1.2, 1.2, (4000, 3))
    pts = np.concatenate([pts, [[0.3, 0.2, 4.0]]])  # behind the camera
    got = inside_mask(torch.as_tensor(pts, dtype=torch.float32), cam, _inner(mask, inset))
    want = _reference_inside(pts, cam, mask, inset)
    # float32 against float64 projection: a point within 1e-4 px of a pixel edge may land either side
    uv, _ = cam.project(pts)
    near_edge = (np.abs(uv - np.round(uv)) < 1e-4).any(1)
    assert (got.numpy() == want)[~near_edge].all()
    assert want.sum() > 100 and (~want).sum() > 100
    assert not got[-1]  # behind the camera
    if inset:
        assert inside_mask(torch.as_tensor(pts, dtype=torch.float32), cam, _inner(mask, 0)).sum() > got.sum()


def test_term_is_the_mean_over_the_layer_inside():
    cam = _camera()
    mask = torch.zeros(30, 40)
    mask[5:26, 8:30] = 1
    # centre of the image (inside), and far off to the side (outside)
    inside_pt, outside_pt = [0.0, 0.0, 0.0], [3.0, 0.0, 0.0]
    means = torch.tensor([inside_pt, inside_pt, outside_pt, inside_pt, outside_pt])
    ids = torch.tensor([0, 5, 6, 7, 8])  # 0: a body Gaussian; 5..8: the layer's (num_body = 5)
    opac = torch.tensor([1.0, 1.0, 1.0, 1.0, 1.0, 0.2, 0.9, 0.6, 0.1], requires_grad=True)
    inner = _inner(mask, 2)
    term = layer_cover_term(opac, means, ids, 5, cam, inner)
    assert torch.allclose(term, torch.tensor(((1 - 0.2) + (1 - 0.6)) / 2))
    term.backward()
    g = opac.grad
    assert torch.allclose(g[[5, 7]], torch.full((2,), -0.5))  # only the layer inside
    assert torch.count_nonzero(g) == 2
    assert layer_cover_term(opac, means[[0, 2]], ids[[0, 2]], 5, cam, inner) is None  # body, or layer outside
    assert layer_cover_term(opac, means[:1], ids[:1], 5, cam, inner) is None


def test_config_and_old_records():
    assert Stage1Config().lambda_layer_cover == 0.03  # on by default (a tight run has no layer: no term)
    with pytest.raises(ValueError, match="lambda_layer_cover"):
        Stage1Config(lambda_layer_cover=-1.0)
    with pytest.raises(ValueError, match="layer_cover_inset"):
        Stage1Config(layer_cover_inset=-1)
    record = Stage1Config().to_dict()
    del record["lambda_layer_cover"]
    assert Stage1Config.from_dict(record).lambda_layer_cover == 0.0  # recorded before the prior


def test_a_step_raises_the_opacity_of_the_layer_inside_the_silhouette(tiny_scene, tiny_config):
    """With the prior alone pulling (rgb / alpha off), one Adam step raises the opacity of exactly
    the layer Gaussians that project inside the frame's mask; at 0, the term is not there."""
    from reconstruct.train.trainer import Trainer

    body = tiny_scene.body_model()
    m = landmark_heights(body)
    layer = build_garment_layer(body, VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05),
                                cols=16, row_step=0.06)
    zero = dict(lambda_rgb=0.0, lambda_ssim=0.0, lambda_normal=0.0, lambda_alpha=0.0, lambda_layer_spacing=0.0,
                lr_layer_skinning=0.0, cull_backfacing=None)
    off = Trainer(tiny_scene, dataclasses.replace(tiny_config, lambda_layer_cover=0.0, **zero), garment_layer=layer)
    assert "layer_cover" not in off.plan.steps["given"](off).terms
    t = Trainer(tiny_scene, dataclasses.replace(tiny_config, lambda_layer_cover=1.0, **zero), garment_layer=layer)
    model, N = t.model, t.model.num_body
    before = model.opacities().detach().clone()
    outcome = t.plan.steps["given"](t)
    assert "layer_cover" in outcome.terms
    i = outcome.frame
    tgt = t.data.targets[i]
    with torch.no_grad():
        posed = model.pose_with(model.canonical(), model.lbs_matrices(t.state.frame_transforms(i)))
    inside = inside_mask(posed.means[N:], tgt.camera, _inner(tgt.mask, t.config.layer_cover_inset))
    assert 0 < int(inside.sum()) < len(inside)
    t.optimizer.zero_grad()
    (outcome.terms["layer_cover"] * outcome.weights["layer_cover"]).backward()
    t.optimizer.step()
    delta = model.opacities().detach()[N:] - before[N:]
    assert (delta[inside] > 0).all()
    assert torch.equal(delta[~inside], torch.zeros_like(delta[~inside]))


def test_a_frames_inner_mask_is_eroded_once_per_inset(tiny_scene):
    """``FrameTarget.inner_mask``: ``evaluate.inner_mask`` of its mask, kept for the next step."""
    from reconstruct.train.data import TrainingData

    tgt = TrainingData(tiny_scene, torch.zeros(3), crop_margin=4).targets[0]
    two = tgt.inner_mask(2)
    assert torch.equal(two, inner_mask(tgt.mask > 0.5, 2))
    assert tgt.inner_mask(2) is two
    one = tgt.inner_mask(1)
    assert torch.equal(one, inner_mask(tgt.mask > 0.5, 1)) and one.sum() > two.sum()
