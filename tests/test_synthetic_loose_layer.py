"""The garment-layer prototype (reconstruct/avatar/garment_layer.py) on the loose-clothing scenes:
the volume hint read from the front masks, a layer that does not tear over the walk, and Gaussians
that cover the gap between the legs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, volume_hint_from_masks
from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene
from reconstruct.data.synthetic.motion import walk_in_place

SMALL = dict(seed=0, num_frames=4, image_size=128, num_eval_azimuths=1, eval_frames=1, texture_size=256)


@pytest.fixture(scope="module")
def scenes():
    return {k: build_synthetic_scene(SyntheticConfig(clothing=k, **SMALL), progress=False) for k in ("garment", "skirt")}


@pytest.fixture(scope="module")
def body(scenes):
    return scenes["skirt"].body_model()


def test_hint_from_masks_finds_the_skirt_and_not_tight_clothes(scenes, body):
    assert volume_hint_from_masks(body, scenes["garment"].frames) is None
    hint = volume_hint_from_masks(body, scenes["skirt"].frames)
    assert hint is not None
    true_hem = scenes["skirt"].meta["loose_garment"]["hem_m"]
    assert abs(hint.hem_z - true_hem) < 0.1, (hint.hem_z, true_hem)
    assert 0.02 <= hint.standoff_hem <= 0.15


def test_layer_does_not_tear_over_the_walk(body):
    marks_hint = VolumeHint(top_z=0.15, hem_z=-0.45, standoff_hem=0.07)
    layer = build_garment_layer(body, marks_hint)
    poses = walk_in_place(body.bone_labels, 60, 20.0, np.random.default_rng(3))[::2]
    stretch = layer.max_neighbour_stretch(body, poses)
    assert stretch < 2.0, stretch
    # the same layer with each Gaussian copying its nearest body vertex's weights tears
    from scipy.spatial import cKDTree

    _, idx = cKDTree(body.canonical_vertices.numpy()).query(layer.positions.numpy())
    nearest = dataclasses.replace(layer, weights=body.skin_weights[idx].to(torch.float32))
    assert nearest.max_neighbour_stretch(body, poses) > 1.5 * stretch
    assert torch.allclose(layer.weights.sum(1), torch.ones(layer.num_gaussians), atol=1e-5)


def test_layer_gaussians_cover_the_gap_between_the_legs(scenes, body):
    from reconstruct.train.render import render_avatar

    hint = volume_hint_from_masks(body, scenes["skirt"].frames)
    layer = build_garment_layer(body, hint)
    f = scenes["garment"].frames[0]
    L = body.bone_labels
    J = body.posed_joints(f.pose).numpy()
    hip = 0.5 * (J[L.index("upperleg01.L")] + J[L.index("upperleg01.R")])
    knee = 0.5 * (J[L.index("lowerleg01.L")] + J[L.index("lowerleg01.R")])
    uv, _ = f.camera.project((hip + 0.6 * (knee - hip))[None])
    u, v = int(uv[0, 0]), int(uv[0, 1])
    assert f.mask[v, u] < 0.5  # the body alone leaves the gap open
    out = render_avatar(layer.gaussians(body, f.pose), f.camera, torch.zeros(3), normals=False)
    alpha = out.alpha.detach().numpy()
    assert alpha[v, u] > 0.5
    # and the layer stays inside the skirt scene's silhouette (it does not spill far out of it)
    skirt_mask = scenes["skirt"].frames[0].mask > 0.5
    spill = (alpha > 0.5) & ~skirt_mask
    assert spill.sum() < 0.15 * (alpha > 0.5).sum()


def test_hint_rejects_bad_heights():
    with pytest.raises(ValueError, match="below the top"):
        VolumeHint(top_z=-0.5, hem_z=0.1)
