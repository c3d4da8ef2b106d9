"""The layer's side profile: ``frame_side_reach`` reads how far a frame's mask reaches past each
posed ring on each side of the body, ``fit_side_profile`` stretches the rings out to it
(``VolumeHint.side_profile``), and ``build_garment_layer`` stretches them and moves the stretched
cloth's weights towards its ring's mean."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from reconstruct.avatar.garment_layer import (SIDE_PROFILE_FALL, SIDE_PROFILE_SLOPE, GarmentLayer, VolumeHint,
                                              build_garment_layer, garment_layer_for, torso_top_height,
                                              volume_hint_from_masks)
from reconstruct.avatar.layer_profile import MIN_SIDE_REACH, fit_side_profile, frame_side_reach
from reconstruct.body.pose import BodyPose
from hint_scenes import clothing_scenes, with_mask

SMALL = dict(seed=0, num_frames=2, image_size=256, num_eval_azimuths=1, eval_frames=1, texture_size=256)


@pytest.fixture(scope="module")
def scene():
    return clothing_scenes(("skirt",), **SMALL)["skirt"]


@pytest.fixture(scope="module")
def body(scene):
    return scene.body_model()


@pytest.fixture(scope="module")
def hint(scene, body):
    h = volume_hint_from_masks(body, scene.frames)
    assert h is not None and not h.two_legs
    return h


def _swung(frame, body, layer, metres: float, rows: tuple[float, float]):
    """``frame`` with its mask widened by ``metres`` (at the hips' depth) past its outer end on the
    body's left over the image rows of the layer's rows from ``rows[0]`` to ``rows[1]`` (shares of
    its height), and metres per pixel there."""
    L = body.bone_labels
    J = body.posed_joints(frame.pose).numpy()
    uv, depth = frame.camera.project(J[[L.index("upperleg01.L"), L.index("upperleg01.R")]])
    mpp = float(depth.mean()) / float(frame.camera.fx)
    towards_left = uv[0, 0] > uv[1, 0]
    R, C = layer.grid_shape
    ys = frame.camera.project(layer.posed(body, frame.pose)[0].numpy())[0][:, 1].reshape(R, C).mean(1)
    top, bottom = int(ys[int(rows[0] * (R - 1))]), int(ys[int(rows[1] * (R - 1))])
    m = np.asarray(frame.mask) > 0.5
    out = m.copy()
    width = int(round(metres / mpp))
    for r in range(top, bottom + 1):
        cols = np.flatnonzero(m[r])
        if towards_left:
            out[r, cols.max() + 1:cols.max() + 1 + width] = True
        else:
            out[r, max(cols.min() - width, 0):cols.min()] = True
    return with_mask(frame, out), mpp


def test_a_symmetric_skirt_keeps_its_layer(scene, body, hint):
    # the benchmark's skirt: the mask reaches past its rings by under a centimetre on both sides (the
    # rows below the hem stand past it), so the layer is the one of the hint alone
    layer = build_garment_layer(body, hint)
    reach = frame_side_reach(body, layer, scene.frames[0])
    assert np.nanmax(reach) < 0.02, np.nanmax(reach)
    assert np.isfinite(reach).mean() > 0.8  # most rows are read: the test says something
    assert fit_side_profile(body, hint, scene.frames) == hint
    assert garment_layer_for(body, scene.frames, "auto").same_as(layer)


def test_a_skirt_swung_to_one_side_is_stretched_out_to_its_mask(scene, body, hint):
    plain = build_garment_layer(body, hint)
    frame, mpp = _swung(scene.frames[0], body, plain, 0.15, (0.35, 0.85))
    before = frame_side_reach(body, plain, frame)
    R = plain.grid_shape[0]
    mid = slice(int(0.45 * R), int(0.75 * R))  # rows well inside the widened band
    # the reading: the mask's new end lies 15 cm past where it was on the left, nothing changed on the right
    assert np.allclose(before[mid, 0], 0.15, atol=3 * mpp), before[mid, 0]
    assert np.nanmax(before[:, 1]) < 0.02
    fitted = fit_side_profile(body, hint, [frame])
    k = np.asarray(fitted.side_profile)
    assert k.shape == (R, 3) and np.allclose(k[:, 0], plain.positions.numpy().reshape(R, -1, 3)[:, 0, 2])
    assert (k[:, 2] == 0).all()  # the right side is not touched
    assert 0.12 < k[mid, 1].min() and k[:, 1].max() < 0.25, k[:, 1]
    assert k[:int(0.2 * R), 1].max() < 0.03  # the rows above the swing stay (smoothing spills a row or so)
    after = frame_side_reach(body, build_garment_layer(body, fitted), frame)
    assert np.abs(after[mid, 0]).max() < 0.02, after[mid, 0]  # the posed layer now reaches the mask's end


def test_a_side_short_of_the_mask_by_less_than_the_threshold_is_left_to_training(scene, body, hint):
    plain = build_garment_layer(body, hint)
    frame, _ = _swung(scene.frames[0], body, plain, 0.6 * MIN_SIDE_REACH, (0.35, 0.85))
    assert np.nanmax(frame_side_reach(body, plain, frame)[:, 0]) > 0.5 * MIN_SIDE_REACH  # read, and
    assert fit_side_profile(body, hint, [frame]) == hint  # left alone


def test_the_stretch_moves_only_that_side_and_its_cloth_follows_the_ring_not_the_thigh(body, hint):
    plain = build_garment_layer(body, hint)
    R, C = plain.grid_shape
    zs = plain.positions.numpy().reshape(R, C, 3)[:, 0, 2]
    knots = np.where(np.arange(R) > R // 3, 0.25, 0.0)
    swung = build_garment_layer(body, replace(hint, side_profile=tuple((float(z), float(a), 0.0)
                                                                        for z, a in zip(zs, knots))))
    # the step from 0 to 25 cm tapers above it at SIDE_PROFILE_SLOPE (a row-by-row reference)
    reach = np.array([max([knots[r]] + [knots[j] - SIDE_PROFILE_SLOPE * abs(zs[r] - zs[j]) for j in range(R)])
                      for r in range(R)])
    assert 0 < reach[R // 3] < 0.25 and reach[0] == 0.0
    p0, p1 = plain.positions.double().reshape(R, C, 3), swung.positions.double().reshape(R, C, 3)
    assert torch.allclose(p1[..., 0].max(1).values - p0[..., 0].max(1).values, torch.as_tensor(reach), atol=1e-6)
    for f in (lambda p: p[..., 0].min(1).values, lambda p: p[..., 1].min(1).values,
              lambda p: p[..., 1].max(1).values, lambda p: p[..., 2]):
        assert torch.allclose(f(p0), f(p1), atol=1e-6)
    # posed with the legs spread (each thigh turned 0.3 rad outwards), the stretched tip's height
    # moves by under half of what its thigh's weights would move it (25 cm past the ring; 4.4 against
    # 9.7 cm when written)
    L = body.bone_labels
    rot = torch.zeros(len(L), 3, dtype=torch.float64)
    rot[L.index("upperleg01.L"), 1] = 0.3
    rot[L.index("upperleg01.R"), 1] = -0.3  # mirrored
    zero = torch.zeros(3, dtype=torch.float64)
    pose, rest = BodyPose(rot, zero, zero), BodyPose(torch.zeros_like(rot), zero, zero)
    row = R * 2 // 3
    i = row * C + int(p1[row, :, 0].argmax())
    rise = lambda layer: float((layer.posed(body, pose)[0][i] - layer.posed(body, rest)[0][i])[2])  # noqa: E731
    w = swung.weights.clone()
    w[i] = plain.weights[i]  # the unstretched point's weights: mostly the left thigh's
    thigh_like = replace(swung, weights=w)
    assert abs(rise(thigh_like)) > 0.05, rise(thigh_like)
    assert abs(rise(swung)) < 0.5 * abs(rise(thigh_like)), (rise(swung), rise(thigh_like))


def test_side_reach_never_falls_faster_than_the_slope(hint):
    """A profile read row by row can drop to 0 within a row (the long-skirt photo: 32 cm to 0 between
    rows 1.9 cm apart, where its slanted hem ended on that side), and the discs of those rows, scaled
    by the grid's step, spanned the jump as needles. The rows below fall back at ``SIDE_PROFILE_FALL``
    (they hang: at 5 the hem's 5 mm rows made a ledge lying almost flat under the cloth), the rows
    above a knot at ``SIDE_PROFILE_SLOPE``; a profile within the slopes is the knots' interpolation."""
    assert SIDE_PROFILE_FALL < SIDE_PROFILE_SLOPE
    zs = np.array([-0.70, -0.713, -0.727, -0.746, -0.751, -0.756, -0.761, -0.766, -0.771])
    h = replace(hint, side_profile=tuple((float(z), float(a), 0.0) for z, a in
                                         zip(zs, [0.277, 0.290, 0.318, 0, 0, 0, 0, 0, 0])))
    z = np.linspace(-0.68, -0.80, 121)
    left, right = h.side_reach(z)
    drop = -np.diff(left) / -np.diff(z)  # metres of stretch lost per metre down
    assert drop.max() <= SIDE_PROFILE_FALL + 1e-9
    np.testing.assert_allclose(h.side_reach(zs)[0][3:], 0.318 - SIDE_PROFILE_FALL * (-0.727 - zs[3:]))
    assert (right == 0).all()
    # the 32 cm row tapers upwards at the steeper slope: above it, the knots' own 27.7-29.0 cm, and
    # 2 cm above the top knot 0.277 - 5 * 0.02
    np.testing.assert_allclose(h.side_reach(np.array([-0.713, -0.68]))[0], [0.290, 0.277 - SIDE_PROFILE_SLOPE * 0.02])
    rise = np.diff(left[z > -0.70]) / -np.diff(z[z > -0.70])  # metres gained per metre down, above the knots
    assert rise.max() <= SIDE_PROFILE_SLOPE + 1e-9
    gentle = replace(hint, side_profile=((0.0, 0.1, 0.0), (-0.1, 0.3, 0.0), (-0.2, 0.25, 0.0)))
    np.testing.assert_allclose(gentle.side_reach(np.array([0.0, -0.05, -0.1, -0.15, -0.2]))[0],
                               [0.1, 0.2, 0.3, 0.275, 0.25])
    # a row-by-row reference of the envelope
    k = np.array(h.side_profile)
    ref = [max([np.interp(-zz, -k[:, 0], k[:, 1], left=0, right=0)]
               + [a - (SIDE_PROFILE_SLOPE * (zz - kz) if zz >= kz else SIDE_PROFILE_FALL * (kz - zz)) for kz, a, _ in k]
               + [0.0]) for zz in z]
    np.testing.assert_allclose(left, ref, atol=1e-12)


def test_the_profile_goes_through_a_checkpoint(body, hint):
    plain = build_garment_layer(body, hint)
    R, C = plain.grid_shape
    zs = plain.positions.numpy().reshape(R, C, 3)[:, 0, 2]
    swung = build_garment_layer(body, replace(hint, side_profile=tuple((float(z), 0.1, 0.05) for z in zs)))
    back = GarmentLayer.from_state(swung.to_state())
    assert back.hint == swung.hint and back.same_as(swung)
    assert "reaching out up to 10.0 cm left and 5.0 cm right" in swung.describe()
    old = swung.to_state()
    del old["hint"]["side_profile"]  # a record from before profiles
    assert GarmentLayer.from_state(old).hint.side_profile == ()
    bad = swung.to_state()
    bad["hint"]["side_profile"] = [[0.1, "wide", 0.0]]
    with pytest.raises(ValueError, match="side_profile must be a list of \\[height, left, right\\] numbers"):
        GarmentLayer.from_state(bad, source="run/checkpoint.pt")
    bad["hint"]["side_profile"] = [[0.1, -0.2, 0.0]]
    with pytest.raises(ValueError, match="run/checkpoint.pt: garment layer: .*reaches >= 0"):
        GarmentLayer.from_state(bad, source="run/checkpoint.pt")


def test_side_reach_interpolates_the_knots_and_is_zero_outside(hint):
    h = replace(hint, side_left=0.01, side_profile=((0.0, 0.1, 0.0), (-0.2, 0.3, 0.2)))
    left, right = h.side_reach(np.array([0.1, 0.0, -0.1, -0.2, -0.3, -0.6]))
    # below the last knot the cloth hangs from it: 0.3 - SIDE_PROFILE_FALL * 0.1 at -0.3, none 30 cm down
    assert np.allclose(left, [0.01, 0.11, 0.21, 0.31, 0.01 + 0.3 - SIDE_PROFILE_FALL * 0.1, 0.01])
    assert np.allclose(right, [0.0, 0.0, 0.1, 0.2, 0.2 - SIDE_PROFILE_FALL * 0.1, 0.0])
    with pytest.raises(ValueError, match="heights decreasing"):
        replace(hint, side_profile=((-0.2, 0.1, 0.0), (0.0, 0.1, 0.0)))
    with pytest.raises(ValueError, match="triples of numbers"):
        replace(hint, side_profile=((0.0, 0.1),))


def test_trousers_get_no_profile(scene, body, hint):
    # even with a mask that reaches far past the layer: two tubes are not stretched
    plain = build_garment_layer(body, hint)
    frame, _ = _swung(scene.frames[0], body, plain, 0.15, (0.35, 0.85))
    legs = replace(hint, two_legs=True)
    assert fit_side_profile(body, legs, [frame]) is legs
    assert fit_side_profile(body, hint, [frame]) != hint  # the same frame stretches one tube


def test_a_flaps_stretch_keeps_its_weights(body):
    flap = VolumeHint(top_z=torso_top_height(body), hem_z=0.0, standoff_top=0.012, standoff_hem=0.012,
                      side_right=0.2)
    assert torch.equal(build_garment_layer(body, flap).weights, build_garment_layer(body, flap, stretch_blend=1e9).weights)
    profiled = replace(flap, side_profile=((0.2, 0.0, 0.2), (0.0, 0.0, 0.2)))
    assert not torch.allclose(build_garment_layer(body, profiled).weights,
                              build_garment_layer(body, profiled, stretch_blend=1e9).weights)
