"""The garment layer over the torso: ``frame_torso_evidence`` reads how far the mask stands out
past the torso's sides above the waist, and ``hint_from_evidence`` raises the layer's top to the
chest for cloth that does (a coat, a dress), with that standoff, and keeps it at the waist
otherwise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import binary_dilation
from scipy.spatial import cKDTree

from reconstruct.avatar.garment_layer import (MIN_TORSO_STANDOFF, HintEvidence, LegEvidence, TorsoEvidence,
                                              VolumeHint, build_garment_layer, frame_torso_evidence,
                                              hint_from_evidence, landmark_heights, torso_top_height,
                                              volume_hint_from_masks)
from reconstruct.body.parts import PART_INDEX
from reconstruct.data.synthetic.garment_mesh import PROFILES
from reconstruct.data.synthetic.motion import walk_in_place
from hint_scenes import clothing_scenes, with_mask

# 256 px: a pixel is about 4 mm at the torso (at 128 px the dress's 1.2 cm would be under 1 px)
SMALL = dict(seed=0, num_frames=2, image_size=256, num_eval_azimuths=1, eval_frames=1, texture_size=256)


@pytest.fixture(scope="module")
def scenes():
    return clothing_scenes(("garment", "coat"), **SMALL)


@pytest.fixture(scope="module")
def body(scenes):
    return scenes["garment"].body_model()


def _metres_per_px(body, frame) -> float:
    """Metres per pixel at the waist joint's depth, from the camera directly."""
    J = body.posed_joints(frame.pose).numpy()
    x = J[body.bone_labels.index("spine03")]
    depth = float(frame.camera.R[2] @ x + frame.camera.t[2])  # world to camera: R x + t
    return depth / float(frame.camera.K[0, 0])


def test_torso_standoff_is_what_the_mask_adds_past_the_body(scenes, body):
    f = scenes["garment"].frames[0]
    tight = frame_torso_evidence(body, f)
    assert tight.testable and abs(tight.standoff) < 0.005, tight  # tight clothes: the body's own width
    mpp = _metres_per_px(body, f)
    m = np.asarray(f.mask) > 0.5
    for k in (2, 4):  # the mask grown sideways by k pixels on each side
        grown = binary_dilation(m, structure=np.ones((1, 3), bool), iterations=k)
        e = frame_torso_evidence(body, with_mask(f, grown))
        assert e.testable
        assert abs((e.standoff - tight.standoff) - k * mpp) < 0.5 * mpp, (k, e.standoff, tight.standoff, mpp)


def test_an_arm_against_the_torso_in_a_few_rows_does_not_decide(scenes, body):
    f = scenes["garment"].frames[0]
    tight = frame_torso_evidence(body, f)
    m = np.asarray(f.mask) > 0.5
    L = body.bone_labels
    J = body.posed_joints(f.pose).numpy()
    uv, _ = f.camera.project(J[[L.index("spine03"), L.index("spine01")]])
    r0, r1 = int(uv[1, 1]), int(uv[0, 1])  # chest down to the waist
    rows = np.arange(r0, r1)
    arm = m.copy()
    few = rows[: len(rows) // 4]  # a quarter of the rows: a hand against the side
    for r in few:
        right = np.flatnonzero(m[r, :int(uv[0, 0]) + 40]).max() if m[r].any() else int(uv[0, 0])
        arm[r, right:right + 8] = True
    e = frame_torso_evidence(body, with_mask(f, arm))
    assert e.testable and abs(e.standoff - tight.standoff) < 0.003, (e, tight)
    # the mask merged with a wide block on every torso row: no row counts, nothing to test
    block = m.copy()
    block[r0 - 10:r1 + 10, :] = True
    assert not frame_torso_evidence(body, with_mask(f, block)).testable


def test_coat_raises_the_layer_to_the_chest_with_its_standoff(scenes, body):
    hint = volume_hint_from_masks(body, scenes["coat"].frames)
    assert hint is not None and not hint.two_legs
    assert hint.top_z == pytest.approx(torso_top_height(body))
    assert hint.top_z > landmark_heights(body)["waist"] + 0.2
    assert abs(hint.standoff_top - PROFILES["coat"].standoff_top) < 0.008, hint.standoff_top


def _cloth(torso: TorsoEvidence | None) -> HintEvidence:
    return HintEvidence(True, True, hem_z=-0.45, flare=0.07, drop=0.3, torso=torso)


def test_hint_top_follows_the_torso_evidence(body):
    waist, chest = landmark_heights(body)["waist"], torso_top_height(body)
    assert hint_from_evidence(body, [_cloth(TorsoEvidence(True, 0.0))] * 3).top_z == waist  # a skirt
    assert hint_from_evidence(body, [_cloth(None)] * 3).top_z == waist  # nothing read
    assert hint_from_evidence(body, [_cloth(TorsoEvidence(False))] * 3).top_z == waist  # nothing testable
    below = hint_from_evidence(body, [_cloth(TorsoEvidence(True, MIN_TORSO_STANDOFF - 0.002))] * 3)
    assert below.top_z == waist and below.standoff_top == VolumeHint(0.1, 0.0).standoff_top
    dress = hint_from_evidence(body, [_cloth(TorsoEvidence(True, s)) for s in (0.014, 0.016, 0.0)])
    assert dress.top_z == chest and dress.standoff_top == pytest.approx(0.014)  # the median of three
    wide = hint_from_evidence(body, [_cloth(TorsoEvidence(True, 0.3))] * 3)
    assert wide.standoff_top == pytest.approx(0.05)  # clipped
    # wide trousers (no cloth between the legs) keep their top at the waist whatever the torso says
    legs = LegEvidence(True, True, hem_z=-0.85, flare=0.05, span=0.3)
    trousers = HintEvidence(True, False, legs=legs, torso=TorsoEvidence(True, 0.03))
    h = hint_from_evidence(body, [trousers] * 3)
    assert h.two_legs and h.top_z == waist


def test_the_weight_filter_spans_the_same_cloth_whatever_the_grid():
    """``weight_diffusion``: the filter tuned on the 1.4 cm grid (3 rows, 6 of 92 columns) exactly
    there, and the same metres down the column and share of the way round on any other grid (at
    1 cm in grid steps it was a third narrower, and the chest layer below stretched past 2 in the
    walk)."""
    from reconstruct.avatar.garment_layer import layer_columns, weight_diffusion

    assert weight_diffusion(0.014, 92) == (3.0, 6.0)
    for step in (0.010, 0.007, 0.02):
        rows, cols = weight_diffusion(step, layer_columns(step))
        assert rows * step == pytest.approx(3.0 * 0.014)
        assert cols / layer_columns(step) == pytest.approx(6.0 / 92)


def test_the_layer_over_the_chest_stands_off_the_torso_and_moves_with_it(body):
    m = landmark_heights(body)
    standoff = 0.02
    hint = VolumeHint(top_z=torso_top_height(body), hem_z=m["knee"] + 0.08, standoff_top=standoff, standoff_hem=0.06)
    layer = build_garment_layer(body, hint)
    P = layer.positions.numpy()
    assert P[:, 2].max() == pytest.approx(hint.top_z, abs=1e-4)
    v = body.canonical_vertices.numpy()
    torso = v[body.vertex_parts == PART_INDEX["torso"]]
    chest = P[(P[:, 2] > m["waist"] + 0.05) & (P[:, 2] < hint.top_z - 0.03)]
    d, _ = cKDTree(torso).query(chest)
    # off the torso by at least most of the standoff all round (the hull spans hollows: more there)
    assert np.percentile(d, 5) > 0.7 * standoff and np.median(d) < 3 * standoff, (np.percentile(d, 5), np.median(d))
    # the chest rows follow the spine, not the arms: the spine's bones carry most of each one's
    # weight (the arms' share, up to a third at the armpits, is the body's own blend there)
    L = body.bone_labels
    spine = [i for i, n in enumerate(L) if n.startswith("spine")]
    w = layer.weights.numpy()[(P[:, 2] > m["waist"] + 0.05)]
    assert w[:, spine].sum(1).min() > 0.6, w[:, spine].sum(1).min()
    assert np.median(w[:, spine].sum(1)) > 0.9
    # and the whole layer, chest rows included, stretches without tearing over the walk
    poses = walk_in_place(L, 60, 20.0, np.random.default_rng(3))[::4]
    assert layer.max_neighbour_stretch(body, poses) < 2.0
