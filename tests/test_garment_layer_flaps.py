"""Flaps: ``frame_flap_evidence`` reads cloth standing out sideways past the body on one side from
the chest down (an open coat's or jacket's flap), and ``hint_from_evidence`` gives a layer that
bulges towards that side when nothing else is loose (``flap_hint``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from reconstruct.avatar.garment_layer import (MIN_FLAP, FlapEvidence, GarmentLayer, HintEvidence, VolumeHint,
                                              build_garment_layer, frame_flap_evidence, hint_from_evidence,
                                              landmark_heights, scene_hint_evidence, torso_top_height)
from hint_scenes import clothing_scenes, with_mask

SMALL = dict(seed=0, num_frames=2, image_size=256, num_eval_azimuths=1, eval_frames=1, texture_size=256)


@pytest.fixture(scope="module")
def scenes():
    return clothing_scenes(("garment", "skirt"), **SMALL)


@pytest.fixture(scope="module")
def body(scenes):
    return scenes["garment"].body_model()


def _geometry(body, frame):
    """(metres per pixel at the waist, image x of the body's right hip and left hip, image rows of
    the chest (spine01) and of the knees)."""
    L = body.bone_labels
    J = body.posed_joints(frame.pose).numpy()
    pick = lambda n: J[L.index(n)]  # noqa: E731
    uv, z = frame.camera.project(np.stack([pick("spine03"), pick("upperleg01.R"), pick("upperleg01.L"),
                                           pick("spine01"), 0.5 * (pick("lowerleg01.L") + pick("lowerleg01.R"))]))
    return float(z[0]) / float(frame.camera.fx), uv[1, 0], uv[2, 0], int(uv[3, 1]), int(uv[4, 1])


def _with_flap(frame, body, width_px: int, rows: tuple[int, int], side: str = "R"):
    """``frame`` with ``width_px`` pixels of mask added past the mask's outer end on the body's
    ``side`` over image ``rows`` (first, last)."""
    _, x_right, x_left, _, _ = _geometry(body, frame)
    m = np.asarray(frame.mask) > 0.5
    out = m.copy()
    towards_left_of_image = (x_right < x_left) == (side == "R")
    for r in range(rows[0], rows[1] + 1):
        cols = np.flatnonzero(m[r])
        if towards_left_of_image:
            out[r, max(cols.min() - width_px, 0):cols.min()] = True
        else:
            out[r, cols.max() + 1:cols.max() + 1 + width_px] = True
    return with_mask(frame, out)


def test_tight_clothes_have_no_flap(scenes, body):
    for f in scenes["garment"].frames:
        e = frame_flap_evidence(body, f)
        assert e.testable and e.left is None and e.right is None, e
    assert hint_from_evidence(body, scene_hint_evidence(body, scenes["garment"].frames)) is None


@pytest.mark.parametrize("side", ["R", "L"])
def test_a_flap_is_read_on_its_side_with_its_width_and_heights(scenes, body, side):
    f = scenes["garment"].frames[0]
    mpp, _, _, chest, knees = _geometry(body, f)
    width = int(np.ceil(0.12 / mpp))  # 12 cm
    bottom = chest + int(0.75 * (knees - chest))
    e = frame_flap_evidence(body, _with_flap(f, body, width, (chest, bottom), side))
    assert e.testable
    found, other = (e.right, e.left) if side == "R" else (e.left, e.right)
    assert other is None, e
    assert found is not None, e
    standoff, top_z, hem_z = found
    # the mask's outer end was moved out by `width` px: the standoff is that, give or take a pixel and
    # the few millimetres the tight mask already stands past the body's outermost pixel
    assert abs(standoff - width * mpp) < 2 * mpp, (standoff, width * mpp)
    assert top_z > hem_z
    # the flap's lowest row lies between the hips and the knees, as drawn (3/4 of the way down)
    marks = landmark_heights(body)
    assert marks["knee"] < hem_z < marks["hips"], (hem_z, marks)


def test_a_short_or_narrow_widening_is_no_flap(scenes, body):
    f = scenes["garment"].frames[0]
    mpp, _, _, chest, knees = _geometry(body, f)
    short = frame_flap_evidence(body, _with_flap(f, body, int(0.12 / mpp), (chest, chest + int(0.08 / mpp))))
    assert short.right is None and short.left is None, short  # 8 cm of height: a hand, not a flap
    narrow = frame_flap_evidence(body, _with_flap(f, body, int(0.5 * MIN_FLAP / mpp), (chest, knees)))
    assert narrow.right is None and narrow.left is None, narrow


def test_flap_hint_only_when_nothing_else_is_loose(body):
    tight = HintEvidence(True, False, flaps=FlapEvidence(True, None, (0.15, 0.3, -0.2)))
    hint = hint_from_evidence(body, [tight])
    assert hint is not None and hint.side_right == pytest.approx(0.15) and hint.side_left == 0.0
    assert hint.top_z == pytest.approx(torso_top_height(body))
    assert hint.hem_z == pytest.approx(-0.2)
    assert not hint.two_legs
    # in fewer than half of the frames: none
    plain = HintEvidence(True, False, flaps=FlapEvidence(True))
    assert hint_from_evidence(body, [tight, plain, plain]) is None
    # cloth between the legs decides as before: the skirt's hint, no bulge
    m = landmark_heights(body)
    skirt = HintEvidence(True, True, hem_z=m["knee"] + 0.1, flare=0.06, drop=0.3,
                         flaps=FlapEvidence(True, (0.2, 0.3, -0.2), None))
    assert hint_from_evidence(body, [skirt]) == hint_from_evidence(body, [HintEvidence(True, True, hem_z=m["knee"] + 0.1,
                                                                                       flare=0.06, drop=0.3)])


def test_the_layer_bulges_towards_the_flap_only(body):
    m = landmark_heights(body)
    top = torso_top_height(body)
    plain = build_garment_layer(body, VolumeHint(top_z=top, hem_z=m["hips"] - 0.1, standoff_top=0.012, standoff_hem=0.012))
    flap = build_garment_layer(body, VolumeHint(top_z=top, hem_z=m["hips"] - 0.1, standoff_top=0.012,
                                                standoff_hem=0.012, side_right=0.15))
    assert flap.grid_shape == plain.grid_shape
    p0, p1 = plain.positions.double(), flap.positions.double()
    # the body's right is -X: the rightmost point of each row moves out by the side's 15 cm
    R, C = plain.grid_shape
    right0, right1 = p0[:, 0].reshape(R, C).min(1).values, p1[:, 0].reshape(R, C).min(1).values
    assert torch.allclose(right0 - right1, torch.full_like(right0, 0.15), atol=0.01), (right0 - right1)
    # the left side, the front and the back stay where they were
    for f in (lambda p: p[:, 0].reshape(R, C).max(1).values, lambda p: p[:, 1].reshape(R, C).min(1).values,
              lambda p: p[:, 1].reshape(R, C).max(1).values):
        assert torch.allclose(f(p0), f(p1), atol=0.01)
    # the hint goes through a checkpoint; a record from before flaps loads with no bulge
    back = GarmentLayer.from_state(flap.to_state())
    assert back.hint == flap.hint and back.same_as(flap)
    old = flap.to_state()
    for k in ("side_left", "side_right"):
        del old["hint"][k]
    assert GarmentLayer.from_state(old).hint.side_right == 0.0
    bad = flap.to_state()
    bad["hint"]["side_right"] = "wide"
    with pytest.raises(ValueError, match="side_left and side_right must be numbers"):
        GarmentLayer.from_state(bad)
    with pytest.raises(ValueError, match="standoffs must be >= 0"):
        VolumeHint(top_z=top, hem_z=0.0, side_left=-0.1)
