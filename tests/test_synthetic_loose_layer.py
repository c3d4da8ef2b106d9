"""The garment-layer prototype (reconstruct/avatar/garment_layer.py) on the loose-clothing scenes:
the volume hint read from the front masks, a layer that does not tear over the walk, and Gaussians
that cover the gap between the legs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, volume_hint_from_masks
from reconstruct.data.synthetic.motion import walk_in_place
from hint_scenes import clothing_scenes, with_mask

SMALL = dict(seed=0, num_frames=4, image_size=128, num_eval_azimuths=1, eval_frames=1, texture_size=256)


@pytest.fixture(scope="module")
def scenes():
    return clothing_scenes(("garment", "skirt"), **SMALL)


@pytest.fixture(scope="module")
def body(scenes):
    return scenes["skirt"].body_model()


def test_hint_from_masks_finds_the_skirt_and_not_tight_clothes(scenes, body):
    assert volume_hint_from_masks(body, scenes["garment"].frames) is None
    hint = volume_hint_from_masks(body, scenes["skirt"].frames)
    assert hint is not None and not hint.two_legs  # one tube round both legs
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


def test_hint_ignores_a_sliver_at_the_crotch_and_a_patch_at_the_ankles(scenes, body):
    """Tight trousers on a body fitted with its crotch a little high cover the body's gap for a few
    centimetres below the crotch; feet touching cover it at the ankles: neither is cloth."""
    from reconstruct.avatar.garment_layer import frame_hint_evidence

    skirt, tight = scenes["skirt"].frames[0], scenes["garment"].frames[0]
    full = frame_hint_evidence(body, skirt)
    assert full.cloth and full.drop > 0.1, full
    first, hem = full.rows
    m_skirt, m_tight = np.asarray(skirt.mask) > 0.5, np.asarray(tight.mask) > 0.5
    # the skirt's mask down to a few centimetres below the crotch, the tight mask below
    metres_per_px = full.drop / (hem - first)
    cut = first + int(0.05 / metres_per_px) + 1
    sliver = m_tight.copy()
    sliver[:cut] |= m_skirt[:cut]
    e = frame_hint_evidence(body, with_mask(tight, sliver))
    assert e.testable and not e.cloth, e
    # and the same down past the hem: cloth again (the test above is not vacuous)
    assert frame_hint_evidence(body, with_mask(tight, m_tight | m_skirt)).cloth
    # the gap filled only over the lowest rows of the legs (feet together): not cloth
    rows = np.flatnonzero(m_tight.any(1))
    ankles = m_tight.copy()
    low = slice(rows.max() - 6, rows.max() - 1)
    cols = np.flatnonzero(m_tight[low].any(0))
    ankles[low, cols.min():cols.max() + 1] = True
    e = frame_hint_evidence(body, with_mask(tight, ankles))
    assert not e.cloth, e


def test_hint_reads_cloth_past_a_notch_at_the_crotch():
    """A body fitted with its thighs touching below a notch at the crotch: the notch's rows are
    tested, the touching ones are not (no gap), and the cloth below them is still cloth."""
    from reconstruct.avatar.garment_layer import _without_isolated_top, body_silhouette, frame_hint_evidence

    scene = clothing_scenes(("skirt",), **{**SMALL, "num_frames": 1, "image_size": 256})["skirt"]
    body, skirt = scene.body_model(), scene.frames[0]
    full = frame_hint_evidence(body, skirt)
    assert full.cloth, full
    first, hem = full.rows
    metres_per_px = full.drop / (hem - first)
    touching = int(np.ceil(0.09 / metres_per_px))  # past max_start (8 cm) below the notch
    assert (hem - first - 2 - touching) * metres_per_px >= 0.10  # the cloth below still drops 10 cm
    sil = body_silhouette(body, skirt).copy()
    sil[first + 2:first + 2 + touching] = True  # no gap between the thighs: rows not tested
    e = frame_hint_evidence(body, skirt, silhouette=sil)
    assert e.cloth and e.rows[0] >= first + 2 + touching, e
    # the notch is what the rule drops: a first run as long as the break is kept
    assert _without_isolated_top([10, 11, 40, 41, 42], 8) == [40, 41, 42]
    assert _without_isolated_top(list(range(10, 19)) + [40, 41], 8) == list(range(10, 19)) + [40, 41]
    assert _without_isolated_top([10, 11, 15, 16], 8) == [10, 11, 15, 16]
    assert _without_isolated_top([5], 8) == [5] and _without_isolated_top([], 8) == []


def test_hint_needs_cloth_in_half_the_testable_frames(scenes, body):
    skirt, tight = scenes["skirt"].frames, scenes["garment"].frames
    one_in_four = [skirt[0], *tight[1:]]
    assert volume_hint_from_masks(body, one_in_four) is None
    three_in_four = [*skirt[:3], tight[3]]
    assert volume_hint_from_masks(body, three_in_four) is not None


def test_hint_flare_is_the_skirts_and_a_hand_beside_it_is_not_cloth(scenes, body):
    """The flare is how far the cloth stands out past the body just above the hem (the benchmark's
    skirt: 7.5 cm); a hand hanging beside the skirt, apart from it, does not widen it."""
    from reconstruct.avatar.garment_layer import frame_hint_evidence
    from reconstruct.data.synthetic.garment_mesh import PROFILES

    hint = volume_hint_from_masks(body, scenes["skirt"].frames)
    assert abs(hint.standoff_hem - PROFILES["skirt"].standoff_hem) < 0.015, hint.standoff_hem
    f = scenes["skirt"].frames[0]
    e = frame_hint_evidence(body, f)
    m = np.asarray(f.mask) > 0.5
    hem = e.rows[1]
    right = np.flatnonzero(m[hem - 2]).max()
    hand = m.copy()
    hand[hem - 6:hem + 1, right + 3:right + 7] = True  # apart from the cloth by two background pixels
    e2 = frame_hint_evidence(body, with_mask(f, hand))
    assert e2.cloth and e2.flare == e.flare, (e.flare, e2.flare)
