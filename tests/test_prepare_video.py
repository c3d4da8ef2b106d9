"""``prepare``: a synthetic scene rendered to mp4 -> scene folder, fit compared with the known poses.

Two end-to-end runs on the same video (frames of ``synthetic:seed=0``, 16 frames, 256x256, two frames
blacked out):
- with the real detector (mediapipe 0.10.21 in its own virtualenv, run as a subprocess). It runs
  when an interpreter with mediapipe is found (``bash scripts/bootstrap.sh test`` makes .venv-video
  and sets WONDERHUMAN_REQUIRE_DETECTOR=1, which turns a missing detector into a failure);
- with ``SyntheticSceneDetector``, a TEST DOUBLE that derives keypoints and masks from the synthetic
  scene's known poses (no mediapipe), so the fit is tested on every machine.

Errors: joints in metres, each pose in its own camera's coordinates with the mid-hip point subtracted
(``evaluate.joint_errors``): 12 limb joints (shoulders, elbows, wrists, hips, knees, ankles); silhouette
IoU of the fitted body's mesh (exact triangle coverage) against the ground-truth masks.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from detector_helpers import detector_python

from reconstruct.data.prepare import (Detections, DetectorError, MediapipeDetector, NoPersonError,
                                      PersonDetector, VideoError, parse_mediapipe_output, prepare_video)
from reconstruct.data.prepare.detector import find_detector_python
from reconstruct.data.prepare.evaluate import in_prepared_frame, joint_errors, mask_iou, prepared_crop
from reconstruct.data.prepare.keypoints import NUM_LANDMARKS, KeypointMap
from reconstruct.data.prepare.silhouette import mesh_silhouette
from reconstruct.data.scene_io import read_scene

BLACK = (6, 7)  # frame positions blacked out in the test video (no person: must be dropped)


@pytest.fixture(scope="module")
def synth():
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    cfg = SyntheticConfig(seed=0, num_frames=16, image_size=256, num_eval_azimuths=1, eval_frames=1,
                          texture_size=256)
    return build_synthetic_scene(cfg, progress=False)


@pytest.fixture(scope="module")
def video(synth, tmp_path_factory):
    from app.export import write_frames

    frames = [f.image.copy() for f in synth.frames]
    for i in BLACK:
        frames[i][:] = 0.0
    path = tmp_path_factory.mktemp("video") / "walk.mp4"
    write_frames(frames, path, synth.fps)
    return path




def _fit_errors(synth, scene_folder: Path, scale_align: bool = False) -> tuple[np.ndarray, np.ndarray, list[int]]:
    scene = read_scene(scene_folder)
    gt = {f.index: f for f in synth.frames}
    used = [f.index for f in scene.frames]
    fit_body, true_body = scene.body_model(), synth.body_model()
    err = joint_errors(fit_body, [f.pose for f in scene.frames], scene.frames[0].camera, true_body,
                       [gt[i].pose for i in used], gt[used[0]].camera, scale_align=scale_align)
    faces, crop = fit_body.faces.numpy(), prepared_crop(scene_folder)
    ious = np.array([mask_iou(mesh_silhouette(fit_body.posed_vertices(f.pose).numpy(), faces, f.camera).astype(float),
                              in_prepared_frame(gt[f.index].mask, crop)) for f in scene.frames])
    return err, ious, used


def _outside_mask(scene_folder: Path) -> float:
    """Share of the fitted body's silhouette outside the scene's person mask (mask <= 0.5), over the frames."""
    scene = read_scene(scene_folder)
    body = scene.body_model()
    faces = body.faces.numpy()
    outside = inside = 0
    for f in scene.frames:
        sil = mesh_silhouette(body.posed_vertices(f.pose).numpy(), faces, f.camera)
        outside += int((sil & (f.mask <= 0.5)).sum())
        inside += int(sil.sum())
    return outside / max(inside, 1)


def _baseline_error(synth, scene_folder: Path, scale_align: bool = False) -> float:
    """Joint error of the fitted global motion with the limbs left in the canonical pose."""
    from reconstruct.body.pose import BodyPose

    scene = read_scene(scene_folder)
    body = scene.body_model()
    gt = {f.index: f for f in synth.frames}
    poses = [BodyPose(body.canonical_joint_rotations(), f.pose.global_orient, f.pose.transl) for f in scene.frames]
    return float(joint_errors(body, poses, scene.frames[0].camera, synth.body_model(),
                              [gt[f.index].pose for f in scene.frames], synth.frames[0].camera,
                              scale_align=scale_align).mean())


# ----- the real detector ------------------------------------------------------------------------------
def test_prepare_mediapipe_end_to_end(synth, video, tmp_path, capsys):
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe==0.10.21 (bash scripts/bootstrap.sh video); "
                    "the fit is still tested with the test double below")
    from app.cli import main

    out = tmp_path / "scene"
    assert main(["prepare", str(video), "--out", str(out), "--detector-python", python]) == 0
    printed = capsys.readouterr().out
    assert "mean keypoint error" in printed and "dropped frames (no person): 6, 7" in printed
    report = json.loads((out / "prepare_report.json").read_text())
    assert [d["index"] for d in report["dropped_frames"]] == list(BLACK)
    assert report["frames_used"] == len(synth.frames) - len(BLACK)
    assert report["detector"]["mediapipe_version"] == "0.10.21"
    err, ious, used = _fit_errors(synth, out)
    assert used == [i for i in range(len(synth.frames)) if i not in BLACK]
    baseline = _baseline_error(synth, out)
    nerr, nbase = _fit_errors(synth, out, scale_align=True)[0], _baseline_error(synth, out, scale_align=True)
    print(f"\nmediapipe: scale-aligned joint error {100 * nerr.mean():.2f} cm (canonical limbs: {100 * nbase:.2f} cm); "
          f"joint error {100 * err.mean():.2f} cm (limbs in canonical pose: {100 * baseline:.2f} cm), "
          f"per joint {np.round(100 * err.mean(0), 1).tolist()}; IoU vs truth {ious.mean():.3f} (min {ious.min():.3f}); "
          f"keypoints {report['mean_keypoint_px_error']:.2f} px; IoU vs detected mask "
          f"{report['mean_silhouette_iou']:.3f}; {report['seconds']}")
    # measured here (shape fitted with the poses, silhouette at 128 px, GrabCut-refined masks):
    # scale-aligned 4.0 cm, raw 5.8 cm, IoU vs truth 0.909 (min 0.895), 2.7 px. Before: 5.3 / 8.6 cm, 0.81
    assert nerr.mean() < 0.045 and nerr.mean() < 0.7 * nbase
    assert err.mean() < 0.07
    assert ious.mean() > 0.88 and ious.min() > 0.85
    assert report["mean_keypoint_px_error"] < 4.0
    assert (out / "prepare_report.png").is_file() and report["person"]["people_found"] == 1
    # the scene folder loads through the ordinary loader
    from reconstruct.data.load import load_scene

    scene = load_scene(out)
    assert len(scene.frames) == 14 and scene.frames[0].camera.name == "video"
    assert np.abs(scene.frames[0].image[scene.frames[0].mask == 0]).max() == 0  # black background


def test_prepare_mediapipe_no_person(tmp_path):
    python = detector_python()
    if python is None:
        pytest.skip("no Python with mediapipe==0.10.21")
    from app.export import write_frames

    path = tmp_path / "empty room.mp4"
    write_frames([np.zeros((128, 128, 3), np.float32)] * 5, path, 10)
    out = tmp_path / "scene"
    with pytest.raises(NoPersonError, match="empty room.mp4.*no person found in any of its 5 frames"):
        prepare_video(path, out, detector=MediapipeDetector(python))
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["empty room.mp4"]


# ----- the test double ----------------------------------------------------------------------------------
class SyntheticSceneDetector(PersonDetector):
    """TEST DOUBLE (not a detector): keypoints, 3D landmarks and masks computed from a synthetic
    scene's known poses, camera and masks, as a perfect mediapipe would report them. Frame positions
    in ``absent`` report no person."""

    name = "synthetic-scene test double"

    def __init__(self, scene, absent=()) -> None:
        self.scene, self.absent = scene, set(absent)

    def detect(self, frames: np.ndarray) -> Detections:
        body = self.scene.body_model()
        kmap = KeypointMap.build(body)
        T = len(frames)
        kp = np.zeros((T, NUM_LANDMARKS, 2))
        vis = np.zeros((T, NUM_LANDMARKS))
        world = np.zeros((T, NUM_LANDMARKS, 3))
        masks = np.zeros(frames.shape[:3], np.float32)
        found = np.ones(T, bool)
        for i, f in enumerate(self.scene.frames[:T]):
            if i in self.absent:
                found[i] = False
                continue
            pts = kmap.points(body.bone_transforms(f.pose)).numpy()
            uv, _ = f.camera.project(pts)
            pc = f.camera.world_to_camera(pts)
            hips = pc[[kmap.index_of("left_hip"), kmap.index_of("right_hip")]].mean(0)
            kp[i, kmap.landmark_ids], vis[i, kmap.landmark_ids] = uv, 1.0
            world[i, kmap.landmark_ids] = pc - hips
            masks[i] = f.mask
        return Detections(kp, vis, world, masks, found, source=self.name)


def test_prepare_fit_with_test_double(synth, video, tmp_path):
    out = tmp_path / "scene"
    folder, report = prepare_video(video, out, detector=SyntheticSceneDetector(synth, BLACK), log=lambda m: None)
    assert folder == out and (out / "prepare_report.json").is_file()
    assert [d["index"] for d in report["dropped_frames"]] == list(BLACK)
    err, ious, used = _fit_errors(synth, out)
    baseline = _baseline_error(synth, out)
    nerr, nbase = _fit_errors(synth, out, scale_align=True)[0], _baseline_error(synth, out, scale_align=True)
    outside = _outside_mask(out)
    print(f"\ntest double: scale-aligned joint error {100 * nerr.mean():.2f} cm (canonical limbs: {100 * nbase:.2f} cm); "
          f"joint error {100 * err.mean():.2f} cm (limbs in canonical pose: {100 * baseline:.2f} cm), "
          f"per joint {np.round(100 * err.mean(0), 1).tolist()}; IoU vs truth {ious.mean():.3f}; "
          f"keypoints {report['mean_keypoint_px_error']:.2f} px; outside the mask {100 * outside:.2f} %; "
          f"fit {report['seconds']['fit']:.1f} s")
    # measured here: scale-aligned 3.6 cm (canonical limbs 8.9 cm), raw 4.7 cm, IoU 0.954, keypoints 0.8 px
    # (before the shape fit: 5.6 / 8.8 cm, 0.90); the scene's 1.82 m body is 12 cm above the stature prior
    assert nerr.mean() < 0.05 and nerr.mean() < 0.6 * nbase
    assert err.mean() < 0.065
    assert ious.mean() > 0.92
    assert report["mean_keypoint_px_error"] < 2.0
    # the fitted body stays within a pixel or two of the person's outline: 3.15 % of its silhouette
    # outside the mask here (1.45 % with the body fitted inside it, docs/prepare.md)
    assert outside < 0.04


def test_limbs_whose_far_ends_the_frame_cuts_off_are_held_straight(synth):
    """A frame cut above the knees (the mask empty below, knee to toe landmarks cut): the legs'
    bones are held near their rest rotation. Without the hold (``cut`` not given) nothing but the
    weak prior sees them, and the same fit turned them by 0.6-1.6 rad (frame 0, whose true legs
    are within 0.1 rad of rest); held, 0.05-0.15."""
    from reconstruct.data.prepare.fit import FIT_BONES, FitConfig, _Problem, fit_poses
    from reconstruct.data.prepare.keypoints import LANDMARK_NAMES

    body = synth.body_model()
    frames = np.stack([f.image for f in synth.frames])
    det = SyntheticSceneDetector(synth).detect(frames).select(np.arange(len(frames)) == 0)
    ids = [i for i, n in enumerate(LANDMARK_NAMES) if any(k in n for k in ("knee", "ankle", "heel", "foot_index"))]
    knees = [LANDMARK_NAMES.index("left_knee"), LANDMARK_NAMES.index("right_knee")]
    det.masks[0, int(det.keypoints[0, knees, 1].min()) - 3:] = 0.0
    det.visibility[0, ids] = 0.0
    det.cut = np.zeros(det.visibility.shape, bool)
    det.cut[0, ids] = True
    legs = ["upperleg01.L", "upperleg01.R", "lowerleg01.L", "lowerleg01.R"]
    P = _Problem(body, det, FitConfig(), None, None)
    held = {FIT_BONES[i] for i in np.flatnonzero(P.held[0].numpy())}
    assert held == set(legs)
    fit = fit_poses(body, det, FitConfig())
    canon, labels = body.canonical_joint_rotations(), list(body.bone_labels)
    turned = [float(np.linalg.norm(fit.poses[0].joint_rotations[labels.index(n)] - canon[labels.index(n)]))
              for n in legs]
    assert max(turned) < 0.25, turned
    # an elbow cut off holds the upper arm, a wrist the forearm; the other frames' bones are free
    two = type(det)(np.repeat(det.keypoints, 2, 0), np.repeat(det.visibility, 2, 0), None,
                    np.repeat(det.masks, 2, 0), np.ones(2, bool), cut=np.zeros((2, len(LANDMARK_NAMES)), bool))
    two.cut[1, LANDMARK_NAMES.index("right_elbow")] = True
    two.cut[1, LANDMARK_NAMES.index("left_wrist")] = True
    P = _Problem(body, two, FitConfig(), None, None)
    assert not P.held[0].any()
    assert {FIT_BONES[i] for i in np.flatnonzero(P.held[1].numpy())} == {"upperarm01.R", "lowerarm01.L"}
    # ``select`` carries the flags; nothing cut: no hold at all
    assert _Problem(body, det.select(np.array([True])), FitConfig(), None, None).held is not None
    det.cut[:] = False
    assert _Problem(body, det, FitConfig(), None, None).held is None


def test_a_straight_thigh_does_not_turn_about_its_own_axis(synth):
    """The thighs' turn about the vertical is all but invisible to a straight leg's keypoints; with
    the prior on it (``_PRIOR``, 40 on z) a frame whose keypoints carry 3 px of noise fits it within
    0.06 rad of the truth. At 1, like the other axes, the same fit turned the thighs by 0.15 and
    0.19 rad (and the photos of shared/real by up to 1.0)."""
    from reconstruct.data.prepare.fit import FitConfig, fit_poses

    body = synth.body_model()
    frames = np.stack([f.image for f in synth.frames])
    det = SyntheticSceneDetector(synth).detect(frames).select(np.arange(len(frames)) == 0)
    det.keypoints = det.keypoints + np.random.default_rng(0).normal(0, 3.0, det.keypoints.shape)
    fit = fit_poses(body, det, FitConfig())
    labels = list(body.bone_labels)
    for n in ("upperleg01.L", "upperleg01.R"):
        i = labels.index(n)
        assert abs(fit.poses[0].joint_rotations[i][2] - synth.frames[0].pose.joint_rotations[i][2]) < 0.06, n


def test_fit_config_rejects_a_negative_mask_growth():
    from reconstruct.data.prepare.fit import FitConfig

    with pytest.raises(ValueError, match="mask_growth must be >= 0 pixels, found -1"):
        FitConfig(mask_growth=-1)
    assert FitConfig(mask_growth=0).mask_growth == 0


def test_fit_rejects_nothing_to_fit_when_no_person(synth, tmp_path):
    """Every frame without a person (stub detector): a clear error naming the video, nothing written."""
    from app.export import write_frames

    path = tmp_path / "clip.mp4"
    write_frames([f.image for f in synth.frames[:3]], path, synth.fps)
    out = tmp_path / "out" / "scene"
    with pytest.raises(NoPersonError, match=r"clip\.mp4: no person found in any of its 3 frames"):
        prepare_video(path, out, detector=SyntheticSceneDetector(synth, absent=range(3)), log=lambda m: None)
    assert not out.exists() and not out.parent.exists()


# ----- bad input --------------------------------------------------------------------------------------
def test_unreadable_video_is_named_and_leaves_nothing(tmp_path, capsys):
    from app.cli import main

    bad = tmp_path / "garbage.mp4"
    bad.write_bytes(os.urandom(4096))
    out = tmp_path / "scene"
    with pytest.raises(VideoError, match=r"garbage\.mp4: cannot be read as a video \(expected a video file"):
        prepare_video(bad, out, detector=SyntheticSceneDetector(None))
    # through the command line: exit code 2 and the same message, before any detector is needed
    assert main(["prepare", str(bad), "--out", str(out), "--detector-python", sys.executable]) == 2
    err = capsys.readouterr().err
    assert "garbage.mp4: cannot be read as a video (expected a video file" in err
    assert main(["prepare", str(tmp_path / "missing.mov"), "--out", str(out)]) == 2
    assert "missing.mov: no such video, image or folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.mp4"]


def test_refuses_to_replace_a_folder_that_is_not_a_scene(tmp_path, video):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    with pytest.raises(ValueError, match="is not a scene folder"):
        prepare_video(video, out, detector=SyntheticSceneDetector(None))
    assert (out / "notes.txt").read_text() == "keep me"


def test_missing_detector_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.delenv("WONDERHUMAN_DETECTOR_PYTHON", raising=False)
    with pytest.raises(DetectorError, match="bootstrap.sh video"):
        find_detector_python(tmp_path / "no-such-python")


# ----- the mediapipe adapter's output parsing ---------------------------------------------------------
def test_parse_mediapipe_output(tmp_path):
    T, H, W = 3, 20, 40
    lm = np.zeros((T, 33, 4), np.float32)
    lm[:, :, 0], lm[:, :, 1], lm[:, :, 3] = 0.25, 0.5, 0.9
    world = np.zeros((T, 33, 4), np.float32)
    world[:, 11, :3] = [0.2, -0.5, 0.1]
    masks = np.zeros((T, H, W), np.uint8)
    masks[:, 5:15, 10:20] = 255
    found = np.array([True, False, True])
    lm[1] = 0.0
    path = tmp_path / "det.npz"
    np.savez(path, found=found, landmarks=lm, world=world, masks=masks, version=np.array("0.10.21"))
    det = parse_mediapipe_output(path, W, H)
    assert det.num_frames == 3 and (det.width, det.height) == (W, H)
    np.testing.assert_allclose(det.keypoints[0, 0], [10.0, 10.0])  # normalised x*W, y*H
    np.testing.assert_allclose(det.visibility[0, 0], 0.9, atol=1e-6)
    assert np.all(det.visibility[1] == 0)  # frame without a person: nothing visible
    np.testing.assert_allclose(det.world[2, 11], [0.2, -0.5, 0.1], atol=1e-6)
    assert det.masks.dtype == np.float32 and det.masks.max() == 1.0 and det.masks[0, 10, 15] == 1.0
    assert det.info["mediapipe_version"] == "0.10.21"
    # wrong shapes and unreadable files name the file
    np.savez(path, found=found, landmarks=lm[:, :17], world=world, masks=masks)
    with pytest.raises(DetectorError, match=r"det\.npz: landmarks have shape"):
        parse_mediapipe_output(path, W, H)
    np.savez(path, found=found, landmarks=lm, world=world, masks=masks)
    with pytest.raises(DetectorError, match=r"det\.npz: masks have shape"):
        parse_mediapipe_output(path, W + 1, H)
    path.write_bytes(b"not a zip")
    with pytest.raises(DetectorError, match="cannot be read"):
        parse_mediapipe_output(path, W, H)


def test_a_video_with_a_display_rotation_is_read_upright(tmp_path):
    """A phone records a portrait video as landscape pixels plus a display matrix; ``read_video`` turns
    every frame as ffmpeg itself does when it shows the file (its own autorotated decode is the
    reference), and the source size is the upright one."""
    import imageio_ffmpeg
    from PIL import Image

    from reconstruct.data.prepare.video import display_rotation, read_video

    ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()
    plain = tmp_path / "plain.mp4"
    subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-f", "lavfi", "-i", "testsrc=size=64x48:rate=10", "-t", "0.5",
                    "-pix_fmt", "yuv420p", str(plain)], check=True)
    for degrees, turns in ((90, 1), (-90, 3), (180, 2)):
        rotated = tmp_path / f"rot{turns}.mp4"
        subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-display_rotation", str(degrees), "-i", str(plain),
                        "-c", "copy", str(rotated)], check=True)
        shown = tmp_path / f"shown{turns}.png"
        subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-i", str(rotated), "-frames:v", "1", str(shown)], check=True)
        reference = np.asarray(Image.open(shown).convert("RGB")).astype(int)
        assert display_rotation(rotated) == turns
        v = read_video(rotated, max_size=None)
        assert v.frames.shape[1:3] == reference.shape[:2] and v.source_size == (reference.shape[1], reference.shape[0])
        assert np.abs(v.frames[0].astype(int) - reference).mean() < 1.0
    assert display_rotation(plain) == 0 and read_video(plain, max_size=None).frames.shape[1:3] == (48, 64)
    assert display_rotation(tmp_path / "missing.mp4") == 0


def test_the_silhouette_gradient_frame_by_frame_is_the_whole_sum_s():
    """``fit._silhouette_grads`` (each frame's graph back-propagated and freed on its own, then one
    backward upstream) gives the parameters the gradient of the whole sum back-propagated at once
    (float64; a toy chain with the fit's shapes: transforms and rest points shared by the frames)."""
    import torch

    from reconstruct.data.prepare.fit import _silhouette_grads

    g = torch.Generator().manual_seed(0)
    theta = torch.randn(5, 3, dtype=torch.float64, generator=g, requires_grad=True)
    base = torch.randn(3, 4, 4, 4, dtype=torch.float64, generator=g)
    pts = torch.randn(6, 3, dtype=torch.float64, generator=g)

    def upstream():
        Tr = base * torch.tanh(theta.sum()) + theta[:3, :1, None, None]  # (T=3,J=4,4,4)
        rv = pts * theta[3] + theta[4] ** 2  # (N=6,3)
        return Tr, rv

    def frame_loss(i, Tr_i, rv):
        return (torch.sin(Tr_i[:, :3, :3].sum(0) @ rv.T) ** 2).mean() * (i + 1)

    Tr, rv = upstream()
    whole = sum(frame_loss(i, Tr[i], rv) for i in range(3)) * 0.7 + (theta ** 2).sum()
    (ref,) = torch.autograd.grad(whole, theta)
    Tr, rv = upstream()
    total, ends = _silhouette_grads(Tr, rv, frame_loss, 0.7)
    other = (theta ** 2).sum()
    torch.autograd.backward([other] + [t for t, _ in ends], [torch.ones_like(other)] + [d for _, d in ends])
    assert len(ends) == 2
    assert torch.allclose(theta.grad, ref, atol=1e-12, rtol=1e-10)
    assert abs(total * 0.7 + float(other) - float(whole)) < 1e-12
