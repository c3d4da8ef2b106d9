"""``prepare`` on what people have: one image, a folder of images, several people in view; the person
crop and its camera; mask hole filling and refinement; a standing body that stays upright from the side.

The fit runs with ``SyntheticSceneDetector`` (a TEST DOUBLE, see test_prepare_video.py) on every
machine; the person choice and the GrabCut refinement also run with mediapipe's interpreter when one
is found (``bash scripts/bootstrap.sh test`` makes it and requires it).
"""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from detector_helpers import detector_python
from PIL import Image

from reconstruct.data.prepare import (Crop, InputError, NoPersonError, PersonCandidate, PersonChoiceError,
                                      choose_person, person_crop, prepare_video)
from reconstruct.data.prepare.crop import apply_crop, edges_cut, near_edges
from reconstruct.data.prepare.fit import FitConfig
from reconstruct.data.prepare.masks import fill_holes, remove_others
from test_prepare_video import SyntheticSceneDetector

QUICK = FitConfig(keypoint_iters=200, silhouette_iters=30)


@pytest.fixture(scope="module")
def synth():
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    cfg = SyntheticConfig(seed=0, num_frames=4, image_size=192, num_eval_azimuths=1, eval_frames=1,
                          texture_size=128)
    return build_synthetic_scene(cfg, progress=False)


def _png(path: Path, image: np.ndarray) -> Path:
    Image.fromarray(np.clip(image * 255 + 0.5, 0, 255).astype(np.uint8)).save(path)
    return path




# ----- inputs and their errors ---------------------------------------------------------------------
def test_single_image_and_folder_inputs(synth, tmp_path):
    img = _png(tmp_path / "person.png", synth.frames[0].image)
    out = tmp_path / "one"
    folder, report = prepare_video(img, out, detector=SyntheticSceneDetector(synth), fit_config=QUICK,
                                   log=lambda m: None)
    assert report["input_kind"] == "image" and report["frames_used"] == 1
    assert (out / "prepare_report.png").is_file() and (out / "prepare_report.json").is_file()
    assert not (out / "prepare_people.png").exists()  # one person: no picture of who is who
    assert report["per_frame"][0]["name"] == "person.png"
    assert report["cut_off"] == {} and report["landmarks_at_cut_edges"] == 0  # the whole body in view
    # a folder: images sorted by name (not by creation order), every one a frame
    shots = tmp_path / "shots"
    shots.mkdir()
    for name, k in (("b_002.png", 2), ("a_001.png", 1), ("c_003.webp", 3)):
        im = (np.clip(synth.frames[k].image, 0, 1) * 255).astype(np.uint8)
        Image.fromarray(im).save(shots / name)
    (shots / "notes.txt").write_text("not an image")
    out = tmp_path / "many"

    class Ordered(SyntheticSceneDetector):
        def detect(self, frames):  # frames must arrive in name order: a_001 (frame 1), b_002 (2), c_003 (3)
            for got, k in zip(frames, (1, 2, 3)):
                want = (np.clip(synth.frames[k].image, 0, 1) * 255).astype(np.float32)
                assert np.abs(got.astype(np.float32) - want).mean() < 3.0
            return super().detect(frames)

    class Shifted:
        frames = synth.frames[1:]
        body_model = synth.body_model

    _, report = prepare_video(shots, out, detector=Ordered(Shifted), fit_config=QUICK, log=lambda m: None)
    assert report["input_kind"] == "folder" and report["frames_used"] == 3
    assert [r["name"] for r in report["per_frame"]] == ["a_001.png", "b_002.png", "c_003.webp"]


def test_input_errors_name_the_path(synth, tmp_path, capsys):
    from app.cli import main

    det = SyntheticSceneDetector(synth)
    with pytest.raises(FileNotFoundError, match=r"nobody\.jpg: no such video, image or folder"):
        prepare_video(tmp_path / "nobody.jpg", tmp_path / "s", detector=det)
    bad = tmp_path / "broken.jpg"
    bad.write_bytes(b"\xff\xd8 this is not a jpeg")
    with pytest.raises(InputError, match=r"broken\.jpg: cannot be read as an image \(expected .jpg"):
        prepare_video(bad, tmp_path / "s", detector=det)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.md").write_text("x")
    with pytest.raises(InputError, match=r"empty: the folder holds no images .*found \['readme.md'\]"):
        prepare_video(empty, tmp_path / "s", detector=det)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    _png(mixed / "a.png", synth.frames[0].image)
    _png(mixed / "b.png", synth.frames[0].image[:100])
    with pytest.raises(InputError, match=r"b\.png: is 192x100 pixels, the folder's first image a\.png is 192x192"):
        prepare_video(mixed, tmp_path / "s", detector=det)
    # no person in the image: named, nothing written
    img = _png(tmp_path / "room.png", np.zeros((64, 64, 3), np.float32))
    with pytest.raises(NoPersonError, match=r"room\.png: no person found in room\.png"):
        prepare_video(img, tmp_path / "s", detector=SyntheticSceneDetector(synth, absent=[0]), log=lambda m: None)
    # through the command line: exit code 2, before any detector is needed
    assert main(["prepare", str(bad), "--out", str(tmp_path / "s")]) == 2
    assert "broken.jpg: cannot be read as an image" in capsys.readouterr().err
    assert main(["prepare", str(empty), "--out", str(tmp_path / "s")]) == 2
    assert "the folder holds no images" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_no_person_in_an_image_with_mediapipe(tmp_path):
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe==0.10.21")
    from reconstruct.data.prepare import MediapipeDetector

    img = _png(tmp_path / "wall.png", np.full((96, 96, 3), 0.7, np.float32))
    with pytest.raises(NoPersonError, match=r"wall\.png: no person found in wall\.png"):
        prepare_video(img, tmp_path / "s", detector=MediapipeDetector(python), log=lambda m: None)
    assert not (tmp_path / "s").exists()


# ----- several people ------------------------------------------------------------------------------
def _cand(x0: float, x1: float, y0: float, y1: float, shape=(100, 200)) -> PersonCandidate:
    region = np.zeros(shape, bool)
    region[int(y0):int(y1), int(x0):int(x1)] = True
    return PersonCandidate((x0, y0, x1, y1), region, np.zeros((33, 2)), np.ones(33))


def test_choose_person_numbering_and_tracking():
    small_left, big_middle, right = _cand(5, 30, 40, 90), _cand(80, 120, 10, 95), _cand(160, 190, 20, 90)
    frames = [[right, small_left, big_middle], [_cand(84, 124, 12, 96), _cand(6, 31, 40, 90)]]
    t = choose_person(frames, 200, 100)
    assert (t.index, t.count, t.picked_by) == (2, 3, "auto")  # largest and most central
    assert t.per_frame[1].box[0] == 84  # followed into the next frame
    assert len(t.others[0]) == 2 and len(t.others[1]) == 1
    t = choose_person(frames, 200, 100, person=3)
    assert t.per_frame[0] is right and t.per_frame[1] is None and t.picked_by == "--person"
    with pytest.raises(PersonChoiceError, match=r"clip\.mp4: --person 4 asked for, but 3 people were found"):
        choose_person(frames, 200, 100, person=4, source="clip.mp4")
    assert choose_person([[], []], 200, 100) is None


def test_two_people_side_by_side_with_mediapipe(synth, tmp_path):
    """Two rendered people pasted side by side (the right one smaller): the larger is picked by default,
    --person 2 takes the other; the other is masked out; the crop's camera puts the fitted joints on
    the chosen person in the source image."""
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe==0.10.21")
    from reconstruct.data.prepare import MediapipeDetector
    from reconstruct.data.scene_io import read_scene

    a = synth.frames[0].image
    b = np.asarray(Image.fromarray((a * 255).astype(np.uint8)).resize((150, 150)), np.float32) / 255.0
    canvas = np.zeros((192, 384, 3), np.float32)
    canvas[:, :192] = a
    canvas[30:180, 215:365] = b
    img = _png(tmp_path / "two people.png", canvas)
    det = MediapipeDetector(python)
    for person, side in ((None, "left"), (2, "right")):
        out = tmp_path / f"scene_{side}"
        _, report = prepare_video(img, out, detector=det, person=person, fit_config=QUICK, log=lambda m: None)
        p = report["person"]
        assert p["people_found"] == 2 and p["picked"] == (1 if side == "left" else 2)
        assert (out / "prepare_people.png").is_file()  # who is who, numbered for --person
        crop = Crop(**report["crop"])
        scene = read_scene(out)
        f = scene.frames[0]
        body = scene.body_model()
        # fitted joints through the crop's camera, mapped back to source pixels, land on the chosen person
        uv, _ = f.camera.project(body.posed_joints(f.pose).numpy())
        src = uv / [crop.out_width / crop.width, crop.out_height / crop.height] + [crop.x0, crop.y0]
        inside = (src[:, 0] < 192) if side == "left" else (src[:, 0] > 200)
        assert inside.mean() > 0.95, (side, src[:, 0].min(), src[:, 0].max())
        # the other person is out of the mask and the image
        other = np.zeros((192, 384), np.float32)
        if side == "left":
            other[30:180, 215:365] = 1.0
        else:
            other[:, :192] = 1.0
        oc = apply_crop(other[None], crop, resample="nearest")[0] > 0.5
        assert not oc.any() or (f.mask[oc].max() == 0 and f.image[oc].max() == 0)
        assert report["mean_silhouette_iou"] > 0.7


def test_a_small_person_in_a_wide_frame_is_found_with_mediapipe(synth):
    """A person at a third of the height of a wide frame (a landscape photo taken from a distance):
    the legacy Pose detector fits the whole frame into its square input and found nobody in any of
    these frames; the square windows of ``mediapipe_worker.detect_one`` find them, and their box is
    where they stand."""
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe==0.10.21")
    from reconstruct.data.prepare import MediapipeDetector

    det = MediapipeDetector(python)
    a = (synth.frames[0].image * 255).astype(np.uint8)
    m = synth.frames[0].mask > 0.5
    for bg, (H, W) in ((0, (480, 853)), (235, (640, 853))):
        canvas = np.full((H, W, 3), bg, np.uint8)
        y0, x0 = H - 192 - 10, W - 192 - 40
        canvas[y0:y0 + 192, x0:x0 + 192][m] = a[m]
        people = det.find_people(canvas[None])[0]
        assert len(people) == 1, (bg, H, W, len(people))
        x_lo, y_lo, x_hi, y_hi = people[0].box
        ys, xs = np.nonzero(m)
        assert abs(x_lo - (x0 + xs.min())) < 25 and abs(x_hi - (x0 + xs.max())) < 25, people[0].box
        assert abs(y_lo - (y0 + ys.min())) < 30 and abs(y_hi - (y0 + ys.max())) < 30, people[0].box


def test_the_detector_reports_progress_frame_by_frame_with_mediapipe(synth, tmp_path):
    """The worker's frames are counted as they are done (a long clip's detection and mask refinement
    took minutes without a line), ``prepare`` logs them, and a worker past its time limit is
    stopped with a clear error."""
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe==0.10.21")
    from reconstruct.data.prepare import MediapipeDetector
    from reconstruct.data.prepare.detector import DetectorError

    frames = np.stack([(f.image * 255).astype(np.uint8) for f in synth.frames[:3]])
    det = MediapipeDetector(python)
    seen = []
    det.progress = lambda stage, done, total: seen.append((stage, done, total))
    det.detect(frames)
    assert [x for x in seen if x[0] == "poses"] == [("poses", k, 3) for k in (1, 2, 3)]
    assert [x for x in seen if x[0] == "masks"] == [("masks", k, 3) for k in (1, 2, 3)]
    seen.clear()
    det.find_people(frames[:2])
    assert seen[0] == ("people", 0, 2) and seen[-1] == ("people", 2, 2)
    logs = []
    prepare_video(_png(tmp_path / "one.png", synth.frames[0].image), tmp_path / "one", detector=det,
                  fit_config=QUICK, log=logs.append)
    assert "detecting poses: 1/1 frames" in " | ".join(logs) and "refining masks: 1/1 frames" in " | ".join(logs)
    with pytest.raises(DetectorError, match=r"did not finish 3 frames within 0\.05 s"):
        MediapipeDetector(python, timeout_s=0.05).detect(frames)


def test_the_command_lines_bars_follow_prepares_steps(capsys):
    """``prepare`` on the command line: a tqdm bar per step, each closed full when its step ends
    (the fit's steps report every 10th step: the last is filled in when the next step starts)."""
    from app.prepare_cmd import StageBars

    bars = StageBars()
    for k in range(4):
        bars("poses", k, 3)
    for k in range(0, 300, 10):
        bars("keypoints", k, 300)
    bars("silhouette", 0, 60)
    assert bars.stage == "silhouette"
    bars.close()
    err = capsys.readouterr().err
    assert "detecting poses: 100%" in err and "3/3" in err
    assert "fitting to keypoints: 100%" in err and "300/300" in err and bars.stage is None


def test_window_search_maps_a_detection_back_onto_the_frame():
    """``detect_one`` on a stand-in detector that sees a person (a bright block) only in square
    images: nobody in the wide frame, found in a window, and its landmarks and segmentation put back
    where the block is in the frame; the largest window size that finds the person wins; without
    windows (a second search after blanking someone out) nothing; a person the whole frame shows is
    taken as found there."""
    from types import SimpleNamespace

    from reconstruct.data.prepare.mediapipe_worker import WINDOWS, detect_one, window_origins

    class SquareOnly:
        def __init__(self):
            self.calls = []

        def process(self, img):
            self.calls.append(img.shape[:2])
            h, w = img.shape[:2]
            ys, xs = np.nonzero(img[..., 0] > 200)
            if h != w or ys.size == 0:
                return SimpleNamespace(pose_landmarks=None, segmentation_mask=None)
            # two landmarks at the block's corners (normalised to the window), the rest at its centre
            pts = [(xs.min() / w, ys.min() / h), (xs.max() / w, ys.max() / h)]
            pts += [(xs.mean() / w, ys.mean() / h)] * 31
            lms = [SimpleNamespace(x=float(x), y=float(y), z=0.1, visibility=0.9) for x, y in pts]
            seg = (img[..., 0] > 200).astype(np.float32)
            return SimpleNamespace(pose_landmarks=SimpleNamespace(landmark=lms), segmentation_mask=seg)

    frame = np.zeros((300, 700, 3), np.uint8)
    frame[120:260, 520:560] = 255  # the person, near the right edge
    pose = SquareOnly()
    assert detect_one(pose, frame, windows=False) is None
    pose.calls.clear()
    lm, seg = detect_one(pose, frame, windows=True)
    W, H = 700, 300
    assert np.allclose(lm[0, :2] * [W, H], [520, 120], atol=0.5) and np.allclose(lm[1, :2] * [W, H], [559, 259], atol=0.5)
    assert seg.shape == (H, W) and (seg > 0.5).sum() == 140 * 40 and seg[120:260, 520:560].min() == 1.0
    side = round(WINDOWS[0] * H)
    assert pose.calls[0] == (H, W) and all(shape == (side, side) for shape in pose.calls[1:]), \
        "the whole frame first, then the full-height windows, which find it"
    assert lm[0, 2] == pytest.approx(0.1 * side / W)
    # the windows cover the frame, start at 0, end at the edge, overlap by at least half a window
    for length, s in ((700, 300), (300, 180), (853, 480), (480, 480), (100, 300)):
        o = window_origins(length, s)
        assert o[0] == 0 and (o[-1] + s == length or (len(o) == 1 and s >= length))
        assert all(b - a <= s / 2 for a, b in zip(o, o[1:]))
    # seen in the whole frame: no windows
    square = np.zeros((300, 300, 3), np.uint8)
    square[50:100, 60:80] = 255
    pose.calls.clear()
    lm, _ = detect_one(pose, square, windows=True)
    assert pose.calls == [(300, 300)] and np.allclose(lm[0, :2] * 300, [60, 50], atol=0.5)


def test_quarter_turns_stand_a_turned_person_up():
    """``people.quarter_turns`` on a person's keypoints turned by each angle: the quarter turns it
    returns, applied to the keypoints as ``np.rot90`` turns the frame, leave the body within 45 deg of
    upright; a lean under 60 deg is kept as it is; frames without the shoulders and hips seen say
    nothing."""
    from reconstruct.data.prepare.people import PersonTrack, quarter_turns

    H = W = 200
    upright = np.zeros((33, 2))
    upright[[11, 12]] = [[90, 60], [110, 60]]  # shoulders
    upright[[23, 24]] = [[92, 120], [108, 120]]  # hips

    def turned(deg):  # the keypoints of the frame turned clockwise by deg about its centre
        a = np.radians(deg)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        return (upright - 100) @ R.T + 100

    def track(kp, vis=1.0):
        c = PersonCandidate((0.0, 0.0, W, H), np.zeros((H, W), bool), kp, np.full(33, vis))
        return PersonTrack(1, 1, "auto", [c, None], [[], []])

    def rot90_points(kp, k):  # where np.rot90(frame, k) puts pixel positions (x right, y down)
        for _ in range(k % 4):
            kp = np.stack([kp[:, 1], W - kp[:, 0]], 1)
        return kp

    for deg, expect in ((0, 0), (30, 0), (-55, 0), (90, 1), (-90, 3), (180, 2), (-175, 2), (120, 1), (250, 3)):
        k, angle = quarter_turns(track(turned(deg)))
        assert k == expect, (deg, k, angle)
        after = rot90_points(turned(deg), k)
        up = after[[11, 12]].mean(0) - after[[23, 24]].mean(0)
        assert abs(np.degrees(np.arctan2(up[0], -up[1]))) <= 45.0 + 1e-6 or k == 0, (deg, k)
    assert quarter_turns(track(turned(180), vis=0.2)) == (0, 0.0)
    # a cartwheel: frames upright, on each side and upside down disagree, and nothing is turned
    wheel = PersonTrack(1, 1, "auto", [track(turned(d)).per_frame[0] for d in (0, 90, 180, 270, 170)], [[]] * 5)
    assert quarter_turns(wheel)[0] == 0
    # most frames upside down, one leaning: turned
    mostly = PersonTrack(1, 1, "auto", [track(turned(d)).per_frame[0] for d in (180, 175, 185, 150)], [[]] * 4)
    assert quarter_turns(mostly)[0] == 2


def test_a_person_on_their_side_is_read_standing_with_mediapipe(synth, tmp_path):
    """A frame stored on its side (no orientation tag): ``prepare`` reads it turned so the person
    stands, says so, and fits as on the upright frame; with ``turn=False`` it keeps the frame as
    stored."""
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe==0.10.21")
    from reconstruct.data.prepare import MediapipeDetector

    det = MediapipeDetector(python)
    upright = synth.frames[0].image
    side = _png(tmp_path / "side.png", np.rot90(upright, 1))  # the head towards the left
    logs = []
    _, up_report = prepare_video(_png(tmp_path / "up.png", upright), tmp_path / "up", detector=det,
                                 fit_config=QUICK, log=lambda m: None)
    _, report = prepare_video(side, tmp_path / "side", detector=det, fit_config=QUICK, log=logs.append)
    assert report["turned_deg"] == 270 and up_report["turned_deg"] == 0
    assert any("reading them turned 270 deg" in m for m in logs)
    assert report["mean_keypoint_px_error"] < up_report["mean_keypoint_px_error"] + 2.0
    assert report["mean_silhouette_iou"] > up_report["mean_silhouette_iou"] - 0.05
    _, kept = prepare_video(side, tmp_path / "kept", detector=det, fit_config=QUICK, turn=False, log=lambda m: None)
    assert kept["turned_deg"] == 0


def test_read_input_turns_images_and_videos(tmp_path):
    from reconstruct.data.prepare.inputs import read_input

    pic = _picture(40, 30)
    Image.fromarray(pic).save(tmp_path / "p.png")
    for k in range(4):
        frame = read_input(tmp_path / "p.png", max_side=None, turns=k)[0].frames[0]
        assert np.array_equal(frame, np.rot90(pic, k))


# ----- crop and camera ------------------------------------------------------------------------------
def test_edges_that_cut_the_person_off():
    # a 600 x 900 frame whose person (a box) runs off its bottom edge, cropped to 400 x 600 source
    # pixels at (100, 300) -> 200 x 300: the frame's bottom is the crop's bottom
    src = np.zeros((900, 600))
    src[350:, 250:350] = 1.0
    cr = Crop(100.0, 300.0, 400.0, 600.0, 200, 300)
    mask = apply_crop(src[None], cr, resample="nearest")[0]
    assert edges_cut(mask, cr, (600, 900)) == ["bottom"]
    # whole in view: nothing; a few stray pixels at an edge are no cut (under min_share)
    src[860:] = 0.0
    assert edges_cut(apply_crop(src[None], cr, resample="nearest")[0], cr, (600, 900)) == []
    src[899, 300] = 1.0
    assert edges_cut(apply_crop(src[None], cr, resample="nearest")[0], cr, (600, 900)) == []
    # a crop reaching past the frame's left edge (padded): the person at that edge is cut there,
    # not at the crop's own left border
    src = np.zeros((900, 600))
    src[100:800, 0:80] = 1.0
    pad = Crop(-100.0, 0.0, 600.0, 900.0, 200, 300)
    m = apply_crop(src[None], pad, resample="nearest")[0]
    assert m[:, :30].max() == 0.0  # the padding
    assert edges_cut(m, pad, (600, 900)) == ["left"]
    # a crop that shares only the frame's left edge: a mask filling it is cut there alone; one
    # inside the frame on every side is cut by none (the crop's own border is no edge of the frame)
    inner = Crop(0.0, 200.0, 300.0, 450.0, 200, 300)
    assert edges_cut(apply_crop(src[None], inner, resample="nearest")[0], inner, (600, 900)) == ["left"]
    assert edges_cut(np.ones((300, 200)), inner, (600, 900)) == ["left"]
    assert edges_cut(np.ones((300, 200)), Crop(50.0, 200.0, 300.0, 450.0, 200, 300), (600, 900)) == []


def test_landmarks_at_an_edge_that_cuts_the_person_off():
    # the crop of the test above (200 x 300 crop pixels for 400 x 600 source pixels at (100, 300)):
    # the frame's bottom edge is the crop's row 300, its left edge lies outside the crop (x = -50)
    cr = Crop(100.0, 300.0, 400.0, 600.0, 200, 300)
    pts = np.array([[100.0, 150.0],   # inside
                    [100.0, 289.0],   # 11 px above the bottom edge: kept
                    [100.0, 291.0],   # 9 px above it: a guess
                    [100.0, 340.0],   # past it
                    [-45.0, 150.0]])  # 5 px inside the left edge
    np.testing.assert_array_equal(near_edges(pts, cr, (600, 900), ["bottom"], 10.0),
                                  [False, False, True, True, False])
    np.testing.assert_array_equal(near_edges(pts, cr, (600, 900), ["bottom", "left"], 10.0),
                                  [False, False, True, True, True])
    assert not near_edges(pts, cr, (600, 900), [], 10.0).any()
    # held straight in the fit: past the edge always, at it only with the detector unsure
    from reconstruct.data.prepare.crop import held_landmarks

    vis = np.array([0.9, 0.9, 0.9, 0.9, 0.9])
    np.testing.assert_array_equal(held_landmarks(pts, vis, cr, (600, 900), ["bottom"], 10.0, 0.5),
                                  [False, False, False, True, False])
    vis[2] = 0.3  # 9 px above the edge, unsure: a guess
    np.testing.assert_array_equal(held_landmarks(pts, vis, cr, (600, 900), ["bottom"], 10.0, 0.5),
                                  [False, False, True, True, False])


def test_crop_camera_reprojects_onto_the_same_pixels():
    from reconstruct.camera import Camera
    from reconstruct.data.prepare.fit import camera_rotation

    W, H = 1280, 720
    K = np.array([[900.0, 0, W / 2], [0, 900.0, H / 2], [0, 0, 1]])
    cam = Camera(K, camera_rotation(), np.array([0.1, -0.2, 4.0]), W, H, name="full")
    crop = person_crop((500.0, 120.0, 700.0, 700.0), W, H, 512)
    assert crop.out_height == 512 and 0.74 <= crop.width / crop.height <= 1.0  # square-ish, person upright
    ck = Camera(crop.intrinsics(K), cam.R, cam.t, crop.out_width, crop.out_height, name="crop")
    pts = np.random.default_rng(0).normal([0, 0, 0], [0.4, 0.2, 0.8], size=(50, 3))
    uv_full, _ = cam.project(pts)
    uv_crop, _ = ck.project(pts)
    np.testing.assert_allclose(uv_crop, crop.to_crop(uv_full), atol=1e-9)
    # the image crop agrees with the coordinate map: a bright pixel lands where to_crop says
    img = np.zeros((1, H, W), np.float32)
    img[0, 400, 600] = 1.0
    out = apply_crop(img, crop, resample="bilinear")[0]
    y, x = np.unravel_index(np.argmax(out), out.shape)
    cx, cy = crop.to_crop(np.array([600.5, 400.5]))
    assert abs(x + 0.5 - cx) <= 1.0 and abs(y + 0.5 - cy) <= 1.0
    # a crop reaching beyond the frame is padded black (the box is near its corner, not at it)
    edge = person_crop((20.0, 40.0, 120.0, 340.0), W, H, 256)
    assert edge.x0 < 0 and apply_crop(np.full((1, H, W, 3), 200, np.uint8), edge)[0][:, :5].max() == 0


def test_a_crop_is_never_padded_past_an_edge_that_cuts_the_person_off():
    W, H = 1000, 1000
    white = np.full((1, H, W, 3), 255, np.uint8)
    # a person cut at the knees with room above the head: the box reaches the bottom edge. Grown by
    # its margin the crop would reach 50 px past it, a black band the mask calls background (the
    # silhouette fit bent the legs back out of it); it is moved up instead, keeping its size
    box = (350.0, 350.0, 650.0, 1000.0)
    free = person_crop(box, W, 2 * H, 512)  # the same box in a taller frame: no edge there
    assert free.y0 + free.height > H
    cut = person_crop(box, W, H, 512)
    assert (cut.width, cut.height) == (free.width, free.height) and cut.y0 + cut.height == H
    assert cut.y0 <= box[1] and cut.x0 == free.x0  # the whole box in, no move sideways
    assert apply_crop(white, cut)[0][-3:].min() == 255  # no black rows at the bottom
    # the same at the left edge, and at a corner; within ``BOX_AT_EDGE`` of an edge counts
    left = person_crop((5.0, 300.0, 300.0, 700.0), W, H, 512)
    assert left.x0 == 0 and apply_crop(white, left)[0][:, :3].min() == 255
    corner = person_crop((0.0, 500.0, 300.0, 1000.0), W, H, 512)
    assert corner.x0 == 0 and corner.y0 + corner.height == H
    assert apply_crop(white, corner)[0].min() == 255
    # a box away from the edges keeps its margin on every side; one cut at both the top and the
    # bottom takes the frame's height
    mid = person_crop((400.0, 200.0, 600.0, 800.0), W, H, 512)
    assert mid.y0 < 200 and mid.y0 + mid.height > 800
    tall = person_crop((400.0, 0.0, 600.0, 1000.0), W, H, 512)
    assert (tall.y0, tall.height) == (0.0, 1000.0)


# ----- masks ----------------------------------------------------------------------------------------
def test_fill_holes_fills_small_enclosed_holes_only():
    m = np.zeros((100, 100), np.float32)
    m[10:90, 30:70] = 1.0
    m[20:23, 40:43] = 0.0  # 9 px: a segmenter mistake (< 1 % of 3,200 px)
    m[40:60, 35:65] = 0.0  # 600 px: a real gap (between arm and body)
    m[80:90, 30:40] = 0.0  # a notch open to the outside: not a hole
    out, n, kept = fill_holes(m)
    assert n == 1 and kept == 0 and out[21, 41] == 1.0 and out[50, 50] == 0.0 and out[85, 35] == 0.0
    others = np.zeros((100, 100), bool)
    others[:, 60:] = True
    assert remove_others(out, others)[:, 60:].max() == 0 and remove_others(out, others)[50, 32] == 1.0


def test_a_small_hole_that_looks_like_the_wall_is_kept_one_like_the_person_is_filled():
    """A cluttered wall behind a grey skirt and a skin arm: a small hole showing the wall's colours
    (a narrow gap between the arm and the body) is kept; one in the skirt's grey (a dark fold the
    segmenter missed) is filled, and so is every small hole without the image."""
    rng = np.random.default_rng(1)
    H, W = 120, 100
    wall = rng.choice(np.array([[0.9, 0.1, 0.1], [0.1, 0.7, 0.6], [0.2, 0.2, 0.9], [0.95, 0.9, 0.2]]), (H, W))
    image = wall.copy()
    m = np.zeros((H, W), np.float32)
    m[10:110, 30:70] = 1.0
    image[10:110, 30:70] = [0.5, 0.5, 0.52]  # the skirt
    image[10:110, 30:38] = [0.8, 0.6, 0.5]  # the arm
    gap = (slice(40, 46), slice(38, 41))  # 18 px between the arm and the skirt: the wall shows
    fold = (slice(80, 84), slice(50, 54))  # 16 px of a darker grey fold
    m[gap] = 0.0
    image[gap] = wall[gap]
    m[fold] = 0.0
    image[fold] = [0.42, 0.42, 0.44]
    out, n, kept = fill_holes(m, image=image)
    assert (n, kept) == (1, 1)
    assert (out[gap] == 0.0).all() and (out[fold] == 1.0).all()
    plain, n, kept = fill_holes(m)
    assert (n, kept) == (2, 0) and (plain[gap] == 1.0).all()


def _in_detector_python(tmp_path, name: str, body: str) -> dict:
    """Runs ``body`` (Python that prints one JSON line last) with the detector's interpreter, the
    prepare folder on its path (``grabcut_refine`` imports from there); skips without one."""
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe/OpenCV")
    script = tmp_path / name
    folder = str(Path(__file__).resolve().parents[1] / "reconstruct" / "data" / "prepare")
    script.write_text(f"import sys, json\nimport numpy as np\nsys.path.insert(0, {folder!r})\n" + body)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    res = subprocess.run([python, str(script)], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_grow_is_the_euclidean_disc_dilation(tmp_path):
    """``grabcut_refine.grow`` (a distance transform, linear in the image whatever the radius) keeps
    exactly the pixels within the radius of the mask, against a brute-force float64 distance."""
    r = _in_detector_python(tmp_path, "grow.py", """
from grabcut_refine import grow
rng = np.random.default_rng(1)
bad = 0
for trial in range(6):
    H, W = 47, 61
    m = rng.random((H, W)) < 0.004 * (trial + 1)
    m[20:24, 10:30] |= trial % 2 == 0
    ys, xs = np.nonzero(m)
    yy, xx = np.mgrid[:H, :W]
    d = np.sqrt((yy[..., None] - ys) ** 2 + (xx[..., None] - xs) ** 2).min(-1)
    for r in (1.0, 2.5, 7.0, 19.0):
        bad += int((grow(m, r) != (d <= r + 1e-9)).sum())
print(json.dumps({"bad": bad, "empty": int(grow(np.zeros((5, 5), bool), 3.0).sum())}))
""")
    assert r == {"bad": 0, "empty": 0}


def test_grabcut_refinement_is_repeatable(tmp_path):
    """The same frame gives the same mask whatever OpenCV's generator did before (GrabCut's and
    k-means' starts draw from it: on this busy wall and patterned skirt two calls differed by 175 px)."""
    r = _in_detector_python(tmp_path, "again.py", """
import cv2
from grabcut_refine import refine_mask
H, W = 160, 120
rng = np.random.default_rng(0)
img = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)                          # a busy wall
img[20:80, 45:75] = (40, 60, 160)
img[80:140, 35:85] = rng.integers(150, 256, (60, 50, 3))                         # a patterned skirt
truth = np.zeros((H, W), bool); truth[20:80, 45:75] = truth[80:140, 35:85] = True
soft = truth.astype(np.float32) * 0.97; soft[100:135, 60:85] = 0.05
kp = np.zeros((33, 2)); vis = np.zeros(33)
for i, (x, y) in {11: (70, 25), 12: (50, 25), 23: (66, 80), 24: (54, 80), 25: (67, 115), 26: (53, 115),
                  27: (67, 150), 28: (53, 150)}.items():
    kp[i] = (x, y); vis[i] = 1.0
a, _ = refine_mask(img, soft, kp, vis)
cv2.randu(np.zeros((50, 50)), 0, 1)
b, _ = refine_mask(img, soft, kp, vis)
print(json.dumps({"differ": int((a != b).sum())}))
""")
    assert r == {"differ": 0}


def test_grabcut_restores_a_bite_and_keeps_the_rest(tmp_path):
    """A light 'skirt' on a light background that the segmenter bit into: the refinement grows it back;
    a refinement that disagrees wildly falls back to the segmenter's mask."""
    r = _in_detector_python(tmp_path, "check.py", """
from grabcut_refine import refine_mask
H, W = 160, 120
img = np.zeros((H, W, 3), np.uint8); img[:] = (225, 225, 215)                  # light wall
img[20:80, 45:75] = (40, 60, 160)                                                # blue top
img[80:140, 35:85] = (250, 240, 190)                                             # light yellow skirt
img[140:155, 50:56] = img[140:155, 64:70] = (90, 60, 40)                         # legs
truth = np.zeros((H, W), bool); truth[20:80, 45:75] = truth[80:140, 35:85] = True
truth[140:155, 50:56] = truth[140:155, 64:70] = True
rng = np.random.default_rng(0)
img = np.clip(img.astype(int) + rng.integers(-6, 7, img.shape), 0, 255).astype(np.uint8)
soft = truth.astype(np.float32) * 0.97
soft[100:135, 60:85] = 0.05                                                      # the bite
kp = np.zeros((33, 2)); vis = np.zeros(33)
for i, (x, y) in {11: (70, 25), 12: (50, 25), 23: (66, 80), 24: (54, 80), 25: (67, 115), 26: (53, 115),
                  27: (67, 150), 28: (53, 150)}.items():
    kp[i] = (x, y); vis[i] = 1.0
out, info = refine_mask(img, soft, kp, vis)
iou = lambda a, b: float((a & b).sum() / (a | b).sum())
raw2 = soft.copy()
bad, info2 = refine_mask(img, raw2, kp, vis, min_agreement=1.01)  # any change counts as disagreeing
print(json.dumps({"before": iou(soft > 0.5, truth), "after": iou(out > 0.5, truth), "used": info["used"],
                  "fallback_used": info2["used"], "fallback_is_raw": bool(np.array_equal(bad, raw2))}))
""")
    assert r["used"] and r["before"] < 0.9 and r["after"] > 0.97, r
    assert not r["fallback_used"] and r["fallback_is_raw"]


# ----- a standing body stays upright from the side ------------------------------------------------------
def test_single_standing_frame_is_upright_from_the_side(synth, tmp_path):
    """One front image of a body standing in its canonical pose: the fitted body, seen from the side,
    leans at most 3 degrees (the depth of one view is free; the upright prior holds it); with the prior off
    the report still gives the lean."""
    from reconstruct.body.pose import BodyPose
    from reconstruct.camera import Camera
    from reconstruct.data.prepare.silhouette import mesh_silhouette

    body = synth.body_model()
    f0 = synth.frames[0]
    pose = BodyPose(body.canonical_joint_rotations(), np.zeros(3), np.asarray(f0.pose.transl))
    mask = mesh_silhouette(body.posed_vertices(pose).numpy(), body.faces.numpy(), f0.camera).astype(np.float32)
    image = np.where(mask[..., None] > 0, np.array([0.8, 0.5, 0.4], np.float32), 0.0).astype(np.float32)

    @dataclass
    class F:
        pose: BodyPose
        camera: Camera
        mask: np.ndarray
        image: np.ndarray

    class Standing:
        frames = [F(pose, f0.camera, mask, image)]
        body_model = synth.body_model

    img = _png(tmp_path / "standing.png", image)
    _, report = prepare_video(img, tmp_path / "s", detector=SyntheticSceneDetector(Standing), log=lambda m: None)
    lean = report["side_lean_deg"]["max_abs"]
    print(f"\nstanding frame: side-view lean {lean:.2f} deg, IoU {report['mean_silhouette_iou']:.3f}, "
          f"height {report['body_height_m']:.2f} m, ambiguity {report['depth_ambiguity']}")
    assert report["depth_ambiguity"]["turn"] == 1.0 and report["depth_ambiguity"]["static"] == 1.0
    assert lean <= 3.0
    assert report["mean_silhouette_iou"] > 0.85


def test_prepare_refuses_a_body_without_the_anny_bones(tmp_path):
    """The fit names Anny's bones; an SMPL body is refused with the names it lacks."""
    import smpl_synth as S
    from reconstruct.body.spec import smpl_body_spec
    from reconstruct.data.prepare.keypoints import KeypointMap

    S.write_model(tmp_path, fmt="npz")
    body = smpl_body_spec((), "neutral", tmp_path).build()
    with pytest.raises(ValueError, match="prepare fits Anny bodies: body model .* has no bones .*upperarm01.L"):
        KeypointMap.build(body)


def test_a_map_of_the_source_frame_is_cropped_as_prepare_cropped_it(tmp_path):
    """``in_prepared_frame`` (the truth's masks compared with a prepared scene's fitted body) with the
    crop read from the scene's report (``prepared_crop``): a 20 px box from x = 10 resized to 10 px
    takes every other pixel's pair; a folder without the report is a clear error that names the file."""
    from reconstruct.data.prepare.evaluate import in_prepared_frame, prepared_crop

    src = np.zeros((20, 40), np.float32)
    src[4:8, 14:18] = 1.0  # a 4 px square 4 px right of the crop's left edge
    (tmp_path / "prepare_report.json").write_text(json.dumps(
        {"crop": {"x0": 10, "y0": 0, "width": 20, "height": 20, "out_width": 10, "out_height": 10}}))
    out = in_prepared_frame(src, prepared_crop(tmp_path))
    assert out.shape == (10, 10)
    assert np.argwhere(out > 0.5).min(0).tolist() == [2, 2] and np.argwhere(out > 0.5).max(0).tolist() == [3, 3]
    assert out[:, 6:].max() == 0.0 and abs(float(out.sum()) - 4.0) < 0.5
    with pytest.raises(ValueError, match=r"prepare_report\.json"):
        prepared_crop(tmp_path / "missing")


def _picture(h: int = 48, w: int = 32) -> np.ndarray:
    """A picture no quarter turn or mirror maps onto itself: a gradient and a block in one corner."""
    y, x = np.mgrid[0:h, 0:w]
    im = np.stack([x * 255 // (w - 1), y * 255 // (h - 1), np.full_like(x, 90)], -1).astype(np.uint8)
    im[2:10, 2:8] = [250, 250, 30]
    return im


def test_a_phone_photo_stored_sideways_is_read_upright(tmp_path):
    """A phone keeps a portrait photo's pixels sideways and writes EXIF orientation 6 ("turn a quarter
    clockwise to show"): ``prepare`` sees the person standing, the size and the pixels of the upright
    picture; without the tag the same pixels stay as stored."""
    from reconstruct.data.prepare.inputs import read_input

    upright = _picture()
    stored = np.rot90(upright, 1)  # a quarter turn counter-clockwise, which tag 6 turns back
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(stored).save(tmp_path / "tagged.jpg", quality=98, exif=exif)
    Image.fromarray(stored).save(tmp_path / "untagged.jpg", quality=98)
    video, _ = read_input(tmp_path / "tagged.jpg", max_side=None)
    assert video.frames.shape[1:3] == upright.shape[:2] and video.source_size == (32, 48)
    assert np.abs(video.frames[0].astype(float) - upright).mean() < 3.0
    plain, _ = read_input(tmp_path / "untagged.jpg", max_side=None)
    assert plain.frames.shape[1:3] == stored.shape[:2]


def test_a_cut_out_is_read_over_a_light_wall(tmp_path):
    """A cut-out PNG's transparent pixels hold any colour (here pure red); they are read as the light
    wall, half-transparent ones blended with it, opaque ones as they are."""
    from reconstruct.data.prepare.inputs import CUTOUT_BACKGROUND, read_input

    rgba = np.zeros((40, 30, 4), np.uint8)
    rgba[..., 0] = 255  # red everywhere, hidden where transparent
    rgba[10:30, 8:22] = [20, 60, 140, 255]  # the person
    rgba[5, :, 3] = 128  # a half-transparent row
    Image.fromarray(rgba, "RGBA").save(tmp_path / "cutout.png")
    frame = read_input(tmp_path / "cutout.png", max_side=None)[0].frames[0].astype(int)
    assert frame[0, 0].tolist() == list(CUTOUT_BACKGROUND)
    assert frame[20, 15].tolist() == [20, 60, 140]
    half = (np.array([255, 0, 0]) * 128 + np.array(CUTOUT_BACKGROUND) * 127) / 255
    assert np.abs(frame[5, 3] - half).max() <= 1


@pytest.mark.parametrize("kind", ["png16", "tiff16", "tiff_int32", "tiff_float01", "tiff_float255"])
def test_a_grey_photo_wider_than_8_bits_is_read_at_its_range(tmp_path, kind):
    """A 16-bit grey PNG or TIFF, and 32-bit integer or float TIFFs (scanners, raw converters,
    medical and machine-vision cameras): Pillow's RGB conversion clips them at 255, and a 16-bit
    photo came out white (``prepare`` then found no person). Each is read as the 8-bit grey it
    holds, within rounding."""
    from reconstruct.data.prepare.inputs import read_input

    grey = (np.add.outer(np.arange(40), np.arange(30)) * 3).astype(np.uint8)  # 0..207, a ramp
    if kind in ("png16", "tiff16"):
        im = Image.fromarray(grey.astype(np.uint16) * 257)  # mode I;16, 65535 = white
        assert im.mode.startswith("I;16")
    elif kind == "tiff_int32":
        im = Image.fromarray(grey.astype(np.int32) * 257)  # mode I, 16-bit values
    elif kind == "tiff_float01":
        im = Image.fromarray(grey.astype(np.float32) / 255)  # mode F, a linear 0-1 image
    else:
        im = Image.fromarray(grey.astype(np.float32))  # mode F holding 0-255
    path = tmp_path / ("grey.png" if kind == "png16" else "grey.tif")
    im.save(path)
    frame = read_input(path, max_side=None)[0].frames[0].astype(int)
    assert frame.shape == (40, 30, 3)
    for c in range(3):
        assert np.abs(frame[..., c] - grey).max() <= 1, (kind, frame[..., c].max())


def _matrix_icc(colorants, gamma: float = 2.2, name: str = "Display P3 (test)") -> bytes:
    """An ICC v2 RGB display profile (matrix and gamma curves), written byte by byte from the ICC
    specification: the primaries' D50 XYZ ``colorants`` (red, green, blue), a pure ``gamma`` curve."""
    import struct

    def s15(v):
        return struct.pack(">i", int(round(v * 65536)))

    def xyz(v):
        return b"XYZ " + b"\0" * 4 + b"".join(s15(c) for c in v)

    d50 = (0.9642, 1.0, 0.8249)
    text = name.encode() + b"\0"
    desc = b"desc" + b"\0" * 4 + struct.pack(">I", len(text)) + text + struct.pack(">IIHB", 0, 0, 0, 0) + b"\0" * 67
    curv = b"curv" + b"\0" * 4 + struct.pack(">IH", 1, int(round(gamma * 256)))
    tags = [(b"desc", desc), (b"wtpt", xyz(d50)), (b"rXYZ", xyz(colorants[0])), (b"gXYZ", xyz(colorants[1])),
            (b"bXYZ", xyz(colorants[2])), (b"rTRC", curv), (b"gTRC", curv), (b"bTRC", curv),
            (b"cprt", b"text" + b"\0" * 4 + b"none\0")]
    start = 128 + 4 + 12 * len(tags)
    table, data = b"", b""
    for sig, body in tags:
        table += sig + struct.pack(">II", start + len(data), len(body))
        data += body + b"\0" * (-len(body) % 4)
    head = (struct.pack(">I", start + len(data)) + b"\0" * 4 + struct.pack(">I", 0x02100000) + b"mntrRGB XYZ "
            + b"\0" * 12 + b"acsp" + b"\0" * 28 + b"".join(s15(c) for c in d50))
    return head + b"\0" * (128 - len(head)) + struct.pack(">I", len(tags)) + table + data


# Display P3's primaries adapted to D50 (as Apple's profile states them), and sRGB's
P3_D50 = ((0.5151, 0.2412, -0.0011), (0.2920, 0.6922, 0.0419), (0.1571, 0.0666, 0.7841))
SRGB_D50 = ((0.4361, 0.2225, 0.0139), (0.3851, 0.7169, 0.0971), (0.1431, 0.0606, 0.7141))


def test_a_photo_with_a_wide_gamut_profile_is_read_in_srgb(tmp_path):
    """A Display P3 photo (iPhones) is read in sRGB: each colour as the profile's primaries and
    curve say, computed here independently (P3 -> XYZ D50 -> sRGB, its piecewise curve), within
    one level; read as sRGB numbers it was duller. A JPEG's blocks the same within its rounding; a
    profile that cannot be parsed leaves the pixels as stored."""
    from reconstruct.data.prepare.inputs import read_input

    colours = np.array([[200, 100, 50], [60, 160, 90], [128, 128, 128], [30, 60, 200]], np.uint8)
    lin = (colours / 255.0) ** 2.2
    srgb_lin = np.linalg.solve(np.array(SRGB_D50).T, np.array(P3_D50).T @ lin.T).T
    enc = np.where(srgb_lin <= 0.0031308, 12.92 * srgb_lin, 1.055 * np.clip(srgb_lin, 0, None) ** (1 / 2.4) - 0.055)
    expected = np.clip(np.round(enc * 255), 0, 255)
    icc = _matrix_icc(P3_D50)
    Image.fromarray(colours[None]).save(tmp_path / "p3.png", icc_profile=icc)
    got = read_input(tmp_path / "p3.png", max_side=None)[0].frames[0, 0].astype(float)
    assert np.abs(got - expected).max() <= 1.0, (got, expected)
    assert np.abs(expected - colours).max() >= 15  # the conversion is not a no-op on these colours
    blocks = np.repeat(np.repeat(colours[None], 16, 0), 16, 1)
    Image.fromarray(blocks).save(tmp_path / "p3.jpg", quality=100, icc_profile=icc, subsampling=0)
    got = read_input(tmp_path / "p3.jpg", max_side=None)[0].frames[0][8, 8::16].astype(float)
    assert np.abs(got - expected).max() <= 3.0, (got, expected)
    Image.fromarray(colours[None]).save(tmp_path / "broken.png", icc_profile=b"not a profile at all")
    assert np.array_equal(read_input(tmp_path / "broken.png", max_side=None)[0].frames[0, 0], colours)


def test_a_folder_is_read_in_frame_order_without_hidden_files(tmp_path):
    """Frames numbered without leading zeros come in the order of their numbers (frame2 before
    frame10; sorted as text, frame10 came second); a Mac's ``._`` metadata file beside each photo
    and other hidden files are left out (they ended the read with 'cannot be read as an image')."""
    from reconstruct.data.prepare.inputs import list_images, read_input

    folder = tmp_path / "shots"
    folder.mkdir()
    for i in (1, 2, 10, 11, 3):
        Image.fromarray(np.full((8, 6, 3), 20 * i, np.uint8)).save(folder / f"frame{i}.png")
    (folder / "._frame1.png").write_bytes(b"\x00\x05\x16\x07 AppleDouble metadata")
    (folder / ".thumb.png").write_bytes(b"not a picture")
    assert [p.name for p in list_images(folder)] == ["frame1.png", "frame2.png", "frame3.png", "frame10.png",
                                                    "frame11.png"]
    video, names = read_input(folder, max_side=None)
    assert names == ["frame1.png", "frame2.png", "frame3.png", "frame10.png", "frame11.png"]
    assert video.frames[:, 0, 0, 0].tolist() == [20, 40, 60, 200, 220]


def test_a_phones_heic_photo_is_read(tmp_path):
    """iPhones store photos as HEIC: read through pillow-heif's opener (which itself applies the file's
    own rotation, its ``irot``, on decode and resets the EXIF tag, so the photo is turned once)."""
    import pillow_heif  # a dependency of the project (pyproject.toml): missing is a failure, not a skip

    from reconstruct.data.prepare.inputs import read_input

    upright = _picture(64, 48)
    pillow_heif.from_bytes(mode="RGB", size=(48, 64), data=upright.tobytes()).save(tmp_path / "photo.heic", quality=95)
    frame = read_input(tmp_path / "photo.heic", max_side=None)[0].frames[0]
    assert frame.shape[:2] == upright.shape[:2]
    assert np.abs(frame.astype(float) - upright).mean() < 6.0


def test_a_photo_whose_exif_cannot_be_read_keeps_its_stored_pixels(tmp_path, monkeypatch):
    """An EXIF block Pillow cannot apply (here: its transpose raises) leaves the photo as stored
    instead of refusing it."""
    from PIL import ImageOps

    from reconstruct.data.prepare.inputs import read_input

    stored = _picture()
    Image.fromarray(stored).save(tmp_path / "photo.png")

    def broken(im, **kwargs):
        raise SyntaxError("not a TIFF file")

    monkeypatch.setattr(ImageOps, "exif_transpose", broken)
    frame = read_input(tmp_path / "photo.png", max_side=None)[0].frames[0]
    assert np.array_equal(frame, stored)


def test_the_report_image_marks_an_edge_that_cuts_the_person_off(tmp_path):
    """``prepare_report.png``: an edge of the frame that cuts the person off is a red line across the
    image panels, and the first panel's title names it; without one, no red line."""
    from PIL import Image

    from reconstruct.data.prepare.lean import SideView
    from reconstruct.data.prepare.report_image import ReportFrame, write_report_image

    h, w = 120, 90
    img = np.full((h, w, 3), 200, np.uint8)
    mask = np.zeros((h, w), np.float32)
    mask[20:, 30:60] = 1.0  # the person runs off the bottom
    side = SideView(np.zeros((40, 40), bool), 0.0, (20.0, 5.0), (20.0, 35.0))

    def reds(cut):
        f = ReportFrame("photo.jpg", img, mask, None, mask > 0.5, 0.9, side, cut)
        out = np.asarray(Image.open(write_report_image(tmp_path / "r.png", [f], "t")).convert("RGB")).astype(int)
        out = out[:, : out.shape[1] * 3 // 4]  # the image panels (the side view draws its lean in red)
        return (out[..., 0] > 180) & (out[..., 1] < 80) & (out[..., 2] < 80), out.shape

    red, shape = reds({"bottom": float(h)})
    none, _ = reds({})
    assert not none.any()
    rows = np.flatnonzero(red.any(1))
    assert red.sum() > 50 and rows.min() > shape[0] // 2  # low in the figure, along the bottom edge
    assert red.any(0).sum() > shape[1] // 2  # across the three image panels


def test_the_people_picture_numbers_everyone_and_shows_the_chosen_one_in_full(tmp_path):
    """``prepare_people.png``: each person's pixels tinted with their number's colour but the chosen
    one's, left as the image has them; written whole (no partial file left)."""
    from reconstruct.data.prepare.report_image import _TINTS, write_people_image

    grey = 120
    img = np.full((120, 160, 3), 30, np.uint8)
    regions = []
    for x0 in (10, 60, 110):
        r = np.zeros((120, 160), bool)
        r[20:110, x0:x0 + 40] = True
        img[r] = grey
        regions.append(r)
    boxes = [(10, 20, 50, 110), (60, 20, 100, 110), (110, 20, 150, 110)]
    path = write_people_image(tmp_path / "prepare_people.png", img, regions, boxes, 2, "3 people")
    assert path.is_file() and not list(tmp_path.glob("*.part*"))
    out = np.asarray(Image.open(path).convert("RGB")).astype(float)

    def count(colour):
        return int((np.abs(out - colour).max(-1) < 6).sum())

    tinted = [0.5 * grey + 0.5 * 255 * _TINTS[i] for i in range(3)]
    assert count(tinted[0]) > 200 and count(tinted[2]) > 200  # the others, tinted
    assert count(tinted[1]) == 0 and count(np.full(3, grey)) > 200  # the chosen one, as it is


def test_a_long_video_and_a_folder_of_big_photos_are_resized_as_they_are_read(tmp_path, monkeypatch):
    """Frames are resized (or cropped) one by one as they are decoded, not after the whole clip is
    held at its own size: a 30-s 4K phone clip held whole is 22 GB. Measured with tracemalloc, which
    sees numpy's buffers (not the video decoder's, so the clip's decoded frames are handed over as
    fresh numpy copies): the peak stays near a few full-size frames, far below the input's size."""
    import tracemalloc

    import imageio.v3 as iio

    from app.export import write_frames
    from reconstruct.data.prepare.inputs import read_input

    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    clip = tmp_path / "clip.mp4"
    write_frames([np.roll(base, 4 * k, axis=1) for k in range(40)], clip, 20)
    decode = iio.imiter
    monkeypatch.setattr(iio, "imiter", lambda *a, **k: (np.array(f) for f in decode(*a, **k)))
    folder = tmp_path / "shots"
    folder.mkdir()
    for k in range(24):
        Image.fromarray(np.roll(base, 7 * k, axis=0)).resize((1600, 1200)).save(folder / f"img{k:02d}.jpg")
    full_clip, full_folder = 40 * 720 * 1280 * 3, 24 * 1200 * 1600 * 3
    for path, whole in ((clip, full_clip), (folder, full_folder)):
        tracemalloc.start()
        try:
            video, names = read_input(path, max_side=64)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert video.frames.shape[0] == len(names) == (40 if path == clip else 24)
        assert max(video.frames.shape[1:3]) == 64
        assert peak < whole / 4, (path.name, peak, whole)
