"""``prepare``'s hands: the crops the hand model sees (``hand_crops.py``), the gate on what it found and
the knuckles put in place of the pose's hand points (``hands.py``), the worker's output read back, and
the fit turning a hand at the wrist to meet them (``fit.FIT_BONES``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from reconstruct.data.prepare import Detections, DetectorError, parse_mediapipe_output
from reconstruct.data.prepare.hand_crops import HAND_POINTS, MIN_REACH, REACH, SIDES, crop_square, hand_box, uncrop
from reconstruct.data.prepare.hands import (INDEX_KNUCKLE, MIDDLE_KNUCKLE, PINKY_KNUCKLE, WRIST, HandGate,
                                            taken_hands, with_hand_keypoints)
from reconstruct.data.prepare.keypoints import LANDMARK_NAMES, NUM_LANDMARKS, KeypointMap

L = LANDMARK_NAMES.index


# ----- the crops -------------------------------------------------------------------------------------
def test_the_workers_hand_points_are_the_pose_landmarks_named_so():
    """``hand_crops`` runs in mediapipe's interpreter, without the project: its own copy of the pose's
    wrist, index and pinky indices must be the ones ``keypoints.LANDMARK_NAMES`` names."""
    for side in SIDES:
        assert HAND_POINTS[side] == tuple(L(f"{side}_{n}") for n in ("wrist", "index", "pinky"))


def test_hand_box_reaches_round_the_hand():
    wrist, index, pinky = np.array([100.0, 50.0]), np.array([110.0, 58.0]), np.array([106.0, 62.0])
    x0, y0, size = hand_box(np.stack([wrist, index, pinky]), height=400)
    tip = 0.5 * (index + pinky)
    reach = np.linalg.norm(tip - wrist)  # 10 px, under 3 % of 400: the floor
    half = round(REACH * max(reach, MIN_REACH * 400))
    assert size == 2 * half
    centre = 0.5 * (wrist + tip)
    assert (x0, y0) == (round(centre[0]) - half, round(centre[1]) - half)
    # a long hand sets the reach itself
    far = np.stack([wrist, wrist + [40.0, 0.0], wrist + [40.0, 10.0]])
    assert hand_box(far, height=400)[2] == 2 * round(REACH * np.linalg.norm([40.0, 5.0]))
    with pytest.raises(ValueError, match=r"\(3,2\) finite"):
        hand_box(np.zeros((2, 2)), height=400)


def test_crop_and_uncrop_round_trip_with_padding():
    img = np.zeros((60, 80, 3), np.uint8)
    img[5, 70] = (255, 10, 20)  # one marked pixel near the top right corner
    box = (50, -10, 40)  # reaches past the top and the right edge
    crop = crop_square(img, box)
    assert crop.shape == (40, 40, 3)
    ys, xs = np.nonzero(crop[..., 0])
    assert (ys.tolist(), xs.tolist()) == ([15], [20])
    assert not crop[:10].any() and not crop[:, 30:].any()  # padding past the image
    # the pixel's centre, normalised to the crop, maps back to the image's
    back = uncrop(np.array([(20 + 0.5) / 40, (15 + 0.5) / 40]), box)
    np.testing.assert_allclose(back, [70.5, 5.5])
    assert not crop_square(img, (200, 200, 10)).any()  # wholly outside: zeros


# ----- the gate and the knuckles ---------------------------------------------------------------------------
def _hand(wrist, direction, spread, palm=20.0):
    """(21,2) a hand's landmarks: wrist, knuckles ``palm`` px along ``direction``, index and pinky
    knuckles ``spread`` palm lengths apart across it."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    n = np.array([-d[1], d[0]])
    h = np.tile(np.asarray(wrist, float), (21, 1))
    mid = np.asarray(wrist, float) + palm * d
    h[1:] = mid
    h[MIDDLE_KNUCKLE] = mid
    h[INDEX_KNUCKLE] = mid + 0.5 * spread * palm * n
    h[PINKY_KNUCKLE] = mid - 0.5 * spread * palm * n
    return h


def _detections(hands, found_hands, frames_found=None):
    T = len(hands)
    kp = np.zeros((T, NUM_LANDMARKS, 2))
    kp[:, L("left_wrist")] = (100.0, 100.0)
    kp[:, L("right_wrist")] = (40.0, 100.0)
    kp[:, L("left_index")] = (130.0, 130.0)  # the pose's own (loose) hand points
    kp[:, L("left_pinky")] = (128.0, 128.0)
    vis = np.full((T, NUM_LANDMARKS), 0.9)
    vis[:, L("left_wrist")] = 0.8
    found = np.ones(T, bool) if frames_found is None else np.asarray(frames_found)
    return Detections(kp, vis * found[:, None], None, np.zeros((T, 8, 8), np.float32), found,
                      hands=np.asarray(hands, float), hands_found=np.asarray(found_hands, bool))


def test_gate_takes_hands_and_refuses_lines_and_strangers():
    right = _hand((40.0, 100.0), (0, 1), 0.7)
    cases = [_hand((102.0, 101.0), (1, 1), 0.6),  # a hand at the pose's wrist: taken
             _hand((102.0, 101.0), (1, 1), 0.03),  # collapsed into a line (a can held): refused
             _hand((150.0, 100.0), (1, 1), 0.6),  # 2.5 palms from the pose's wrist: someone else's
             _hand((102.0, 101.0), (1, 1), 0.6, palm=1.0)]  # a dot: no hand
    det = _detections([np.stack([c, right]) for c in cases], np.ones((4, 2), bool))
    np.testing.assert_array_equal(taken_hands(det), [[True, True], [False, True], [False, True], [False, True]])
    # nothing found, or the frame without a person: nothing taken
    det = _detections([np.stack([cases[0], right])] * 2, [[False, True], [True, True]], frames_found=[True, False])
    np.testing.assert_array_equal(taken_hands(det), [[False, True], [False, False]])
    # 0.9 palm lengths off: taken (a mirrored photo's hand came out 0.82 off); 1.2: refused
    near = _hand((100.0 + 18.0 / np.sqrt(2), 100.0 + 18.0 / np.sqrt(2)), (1, 1), 0.6)
    far = _hand((100.0 + 24.0 / np.sqrt(2), 100.0 + 24.0 / np.sqrt(2)), (1, 1), 0.6)
    det = _detections([np.stack([near, right]), np.stack([far, right])], np.ones((2, 2), bool))
    np.testing.assert_array_equal(taken_hands(det)[:, 0], [True, False])
    # the thresholds are the gate's
    loose = HandGate(min_spread=0.01, max_wrist_offset=3.0, min_palm_px=0.5)
    det = _detections([np.stack([c, right]) for c in cases], np.ones((4, 2), bool))
    assert taken_hands(det, loose)[:, 0].all()


def test_knuckles_replace_the_pose_hand_points_or_leave_them_out():
    good = _hand((102.0, 101.0), (1, 1), 0.6)
    det = _detections([np.stack([good, good]), np.stack([_hand((102.0, 101.0), (1, 1), 0.03), good])],
                      np.ones((2, 2), bool))
    out, taken = with_hand_keypoints(det)
    np.testing.assert_array_equal(taken[:, 0], [True, False])
    np.testing.assert_allclose(out.keypoints[0, L("left_index")], good[INDEX_KNUCKLE])
    np.testing.assert_allclose(out.keypoints[0, L("left_pinky")], good[PINKY_KNUCKLE])
    assert out.visibility[0, L("left_index")] == out.visibility[0, L("left_pinky")] == pytest.approx(0.8)
    # refused: the pose's points are left out, not kept
    assert out.visibility[1, L("left_index")] == out.visibility[1, L("left_pinky")] == 0.0
    np.testing.assert_allclose(out.keypoints[1, L("left_index")], (130.0, 130.0))
    # the right hand (its wrist 62 px from this hand) is nobody's here: refused in both frames
    assert not taken[:, 1].any() and not out.visibility[:, L("right_index")].any()
    # the rest is untouched, the input too
    others = [i for i in range(NUM_LANDMARKS) if "index" not in LANDMARK_NAMES[i] and "pinky" not in LANDMARK_NAMES[i]]
    np.testing.assert_array_equal(out.visibility[:, others], det.visibility[:, others])
    assert det.visibility[1, L("left_index")] == 0.9
    # a detector without a hand model: as it was
    plain = dataclasses.replace(det, hands=None, hands_found=None)
    same, none = with_hand_keypoints(plain)
    assert same is plain and not none.any()


def test_detections_check_and_carry_hands():
    det = _detections([np.stack([_hand((0, 0), (1, 0), 0.5)] * 2)] * 3, np.ones((3, 2), bool))
    sub = det.select(np.array([True, False, True]))
    assert sub.hands.shape == (2, 2, 21, 2) and sub.hands_found.shape == (2, 2)
    with pytest.raises(DetectorError, match="hands and hands_found come together"):
        dataclasses.replace(det, hands_found=None)
    with pytest.raises(DetectorError, match=r"hands have shape \(3, 2, 20, 2\)"):
        dataclasses.replace(det, hands=det.hands[:, :, :20])
    bad = det.hands.copy()
    bad[0, 0, 3, 1] = np.nan
    with pytest.raises(DetectorError, match="non-finite"):
        dataclasses.replace(det, hands=bad)


def test_worker_output_with_hands_is_read_in_pixels(tmp_path):
    T, H, W = 2, 40, 60
    lm = np.zeros((T, NUM_LANDMARKS, 4), np.float32)
    lm[..., 3] = 1.0
    hands = np.full((T, 2, 21, 2), 0.5, np.float32)
    hands[0, 1, 0] = (0.25, 0.75)
    found = np.array([True, False])
    path = tmp_path / "out.npz"
    np.savez(path, found=found, landmarks=lm, masks=np.zeros((T, H, W), np.uint8), hands=hands,
             hands_found=np.ones((T, 2), bool))
    det = parse_mediapipe_output(path, W, H)
    np.testing.assert_allclose(det.hands[0, 1, 0], (15.0, 30.0))
    np.testing.assert_array_equal(det.hands_found, [[True, True], [False, False]])  # not where no person
    # an older worker's output has none: no hand model ran
    np.savez(path, found=found, landmarks=lm, masks=np.zeros((T, H, W), np.uint8))
    assert parse_mediapipe_output(path, W, H).hands is None
    np.savez(path, found=found, landmarks=lm, masks=np.zeros((T, H, W), np.uint8), hands=hands[:, :, :5])
    with pytest.raises(DetectorError, match=r"out.npz: hands have shape \(2, 2, 5, 2\).*hands_found is missing"):
        parse_mediapipe_output(path, W, H)


# ----- the fit ---------------------------------------------------------------------------------------
def test_a_video_hand_missed_for_a_few_frames_is_not_held():
    """A wrist is held at rest only in frames with no knuckles within ``HAND_GAP`` frames: a hand the
    model misses now and then keeps its turn through the smoothness term."""
    from reconstruct.data.prepare.fit import HAND_GAP, _hand_unseen

    assert HAND_GAP == 3
    seen = lambda *frames: np.isin(np.arange(12), frames)[:, None] * np.ones((1, 2))  # noqa: E731
    np.testing.assert_array_equal(_hand_unseen(seen(0, 2, 4, 6, 8, 10, 11)), np.zeros(12, bool))
    np.testing.assert_array_equal(np.flatnonzero(_hand_unseen(seen(6, 7))), [0, 1, 2, 11])  # 3-5, 8-10 near
    np.testing.assert_array_equal(np.flatnonzero(_hand_unseen(seen())), np.arange(12))
    np.testing.assert_array_equal(_hand_unseen(np.zeros((1, 2))), [True])  # a photo without the hand
    one_knuckle = np.zeros((3, 2))
    one_knuckle[1, 0] = 0.7
    assert not _hand_unseen(one_knuckle).any()



@pytest.fixture(scope="module")
def synth():
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    cfg = SyntheticConfig(seed=0, num_frames=1, image_size=256, num_eval_azimuths=1, eval_frames=1,
                          texture_size=128)
    return build_synthetic_scene(cfg, progress=False)


def _knuckle_directions(body, pose, camera):
    """(2,2,3) unit vectors, camera space, from each wrist to its index and pinky knuckles."""
    J = body.posed_joints(pose).detach().numpy().astype(np.float64)
    pc = camera.world_to_camera(J)
    lab = body.bone_labels
    out = []
    for s in ("L", "R"):
        w = pc[lab.index(f"wrist.{s}")]
        v = np.stack([pc[lab.index(f"finger2-1.{s}")] - w, pc[lab.index(f"finger5-1.{s}")] - w])
        out.append(v / np.linalg.norm(v, axis=1, keepdims=True))
    return np.stack(out)


def test_fit_turns_a_hand_at_the_wrist_to_its_knuckles(synth):
    """The person's left hand turned 0.7 rad at the wrist in the image plane (about the camera's
    axis), the right one not. With the knuckles (perfect ones, as the hand model would find them) the
    fit turns the left hand to within a few degrees of the truth; with them left out (no hand taken)
    the wrist is held, and the hand keeps the forearm's direction, 40 degrees off."""
    from reconstruct.data.prepare.fit import FIT_BONES, FitConfig, _Problem, fit_poses
    from reconstruct.data.prepare.silhouette import mesh_silhouette

    body = synth.body_model()
    f = synth.frames[0]
    rot = f.pose.joint_rotations.copy()
    rot[body.bone_labels.index("wrist.L")] += (0.0, 0.7, 0.0)  # world Y: the camera looks along it
    pose = dataclasses.replace(f.pose, joint_rotations=rot)
    kmap = KeypointMap.build(body)
    pts = kmap.points(body.bone_transforms(pose)).numpy()
    uv, _ = f.camera.project(pts)
    pc = f.camera.world_to_camera(pts)
    kp, vis, world = np.zeros((1, NUM_LANDMARKS, 2)), np.zeros((1, NUM_LANDMARKS)), np.zeros((1, NUM_LANDMARKS, 3))
    kp[0, kmap.landmark_ids], vis[0, kmap.landmark_ids] = uv, 1.0
    world[0, kmap.landmark_ids] = pc - pc[[kmap.index_of("left_hip"), kmap.index_of("right_hip")]].mean(0)
    mask = mesh_silhouette(body.posed_vertices(pose).numpy(), body.faces.numpy(), f.camera)  # the turned hand's
    det = Detections(kp, vis, world, mask[None].astype(np.float32), np.ones(1, bool))
    truth = _knuckle_directions(body, pose, f.camera)
    config = FitConfig(fit_shape=False)

    def angles(d, cfg):
        fit = fit_poses(body, d, cfg)
        got = _knuckle_directions(body, fit.poses[0], fit.camera)
        return np.degrees(np.arccos(np.clip((got * truth).sum(-1), -1, 1)))  # (2 hands, 2 knuckles)

    with_knuckles = angles(det, config)
    assert with_knuckles.max() < 8.0, with_knuckles
    # the knuckles turn it, not the silhouette: keypoints alone do it too, and without the knuckles
    # the wrist is held (``_Problem.held``), so the hand stays along the forearm
    keypoints_only = dataclasses.replace(config, silhouette_iters=0)
    assert angles(det, keypoints_only).max() < 8.0
    blind = det.visibility.copy()
    blind[0, [L("left_index"), L("left_pinky")]] = 0.0
    blind_det = dataclasses.replace(det, visibility=blind)
    held = _Problem(body, blind_det, config).held
    assert held is not None and {FIT_BONES[i] for i in np.flatnonzero(held[0].numpy())} == {"wrist.L"}
    assert _Problem(body, det, config).held is None
    without = angles(blind_det, keypoints_only)
    assert without[0].mean() > 20.0, without  # the left hand along the forearm (measured: 17 and 37 degrees)
    assert without[1].max() < 8.0, without  # the right hand's knuckles are still there
