"""`export RUN --motion FILE`: a BVH written by an independent library (bvhio) and an SMPL-layout
.npz drive the trained avatar in a video (and a .ply sequence); the clip starts where the video's
first frame stands, resampled to the export's frame rate; the retargeting notes are printed; broken
motion files are refused with nothing written. Timings are printed."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from tiny_runs import train_tiny

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    run = tmp_path_factory.mktemp("motion_run") / "run"
    return train_tiny(run)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from motion_files import write_test_bvh, write_test_npz

    folder = tmp_path_factory.mktemp("motion_files")
    return {"bvh": write_test_bvh(folder / "arms.bvh", frames=40, fps=30.0),
            "npz": write_test_npz(folder / "elbow.npz", frames=30, fps=60.0)}


def test_bvh_video_with_notes_and_timing(run, files, tmp_path, capsys):
    from app.cli import main

    t0 = time.perf_counter()
    assert main(["export", str(run), "--motion", str(files["bvh"]), "--out", str(tmp_path / "arms.mp4"),
                 "--size", "64", "--fps", "15", "--quiet"]) == 0
    dt = time.perf_counter() - t0
    out = capsys.readouterr().out
    # 40 frames at 30 fps (1.3 s) resampled to 15 fps: 20 frames
    assert "arms.bvh: 40 frames at 30 fps -> 20 frames at 15 fps" in out, out
    assert "LeftHandIndex1" in out and "dropped" in out  # the notes: a finger the avatar has no bone for
    assert "grounded" in out
    frames = iio.imread(tmp_path / "arms.mp4", index=None, plugin="pyav")
    assert frames.shape == (20, 64, 64, 3)
    assert iio.immeta(tmp_path / "arms.mp4", plugin="pyav")["fps"] == pytest.approx(15.0)
    lit = (frames.max(-1) > 40).mean(axis=(1, 2))
    assert lit.min() > 0.02  # the avatar is in every frame
    # T-pose at the start, arms down in the middle: the lit area is widest at the ends
    widths = [int(np.ptp(np.nonzero((f.max(-1) > 40).any(0))[0])) for f in frames]
    assert widths[0] > widths[10] + 5, widths
    print(f"\n[export --motion] BVH 40 frames -> 20 at 64 px: {dt:.2f} s (resume, retarget, render, encode); "
          f"{out.splitlines()[0]}")


def test_npz_gif_cut_and_loop_and_ply_sequence(run, files, tmp_path, capsys):
    from app.cli import main
    from reconstruct.ply import read_gaussians_ply

    # 30 frames at 60 fps = 0.483 s; cut 0.1..0.4 s at the scene's 20 fps, looped: the end frame left out
    assert main(["export", str(run), "--motion", str(files["npz"]), "--start", "0.1", "--end", "0.4", "--loop",
                 "--out", str(tmp_path / "elbow.gif"), "--size", "48", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "elbow.npz: 30 frames at 60 fps -> 6 frames at 20 fps" in out, out
    assert "looped" in out and "hand/face joints ignored" in out
    gif = iio.imread(tmp_path / "elbow.gif", index=None)
    assert gif.shape[:3] == (6, 48, 48)
    assert main(["export", str(run), "--motion", str(files["npz"]), "--ply", str(tmp_path / "elbow"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "-> 10 frames at 20 fps" in out and "wrote " + str(tmp_path / "elbow") + " (10 frames" in out
    plys = sorted((tmp_path / "elbow").iterdir())
    assert len(plys) == 10
    first, last = (read_gaussians_ply(p).means for p in (plys[0], plys[-1]))
    assert np.abs(first - last).max() > 0.05  # the elbow bent


def test_motion_starts_on_the_video_and_stands_on_its_floor(run, files):
    """Placement (docs/motion.md): hips start above the video's first frame's hips, feet on the
    lowest foot of the video's poses."""
    from app.export import motion_poses
    from reconstruct.run_folder import RunFolder

    avatar = RunFolder(run).resume().avatar()
    body, scene = avatar.body, avatar.scene
    m = motion_poses(avatar, files["bvh"])
    assert m.fps == scene.fps and len(m) == 27  # 1.3 s at the scene's 20 fps
    labels = list(body.bone_labels)
    root = labels.index("root")
    first = body.posed_joints(m.poses[0]).numpy()
    video = body.posed_joints(scene.frames[0].pose).numpy()
    assert np.linalg.norm(first[root, :2] - video[root, :2]) < 0.05  # Z up: the same place on the floor

    def lowest(pose):
        return float(body.posed_vertices(pose).numpy()[:, 2].min())

    floor = min(lowest(f.pose) for f in scene.frames)
    clip_low = min(lowest(p) for p in m.poses)
    print(f"\n[export --motion] floor of the video {floor:.3f} m, lowest point of the clip {clip_low:.3f} m")
    assert abs(clip_low - floor) < 0.03


def test_broken_motion_files_are_refused_and_nothing_is_written(run, files, tmp_path, capsys):
    from app.cli import main

    text = Path(files["bvh"]).read_text()
    (tmp_path / "xscale.bvh").write_text(text.replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                                                      "CHANNELS 3 Xscale Xrotation Yrotation", 1))
    (tmp_path / "cut.bvh").write_text(text[: len(text) - 400])
    (tmp_path / "empty.bvh").write_text(text[: text.index("MOTION")] + "MOTION\nFrames: 0\nFrame Time: 0.0333\n")
    np.savez(tmp_path / "objects.npz", poses=np.zeros((4, 72)), gender=np.array([{"a": 1}], dtype=object))
    (tmp_path / "walk.pkl").write_bytes(b"\x80\x04K\x01.")
    work = sorted(p.name for p in tmp_path.iterdir())
    cases = [("xscale.bvh", "unsupported channel 'Xscale'"), ("cut.bvh", "cut.bvh"),
             ("empty.bvh", "empty motion"), ("objects.npz", "pickled Python objects"),
             ("walk.pkl", "pickle files are refused"), ("nope.bvh", "no such motion file")]
    for name, expect in cases:
        for out in (["--out", str(tmp_path / "x.mp4")], ["--ply", str(tmp_path / "x")]):
            assert main(["export", str(run), "--motion", str(tmp_path / name), *out, "--quiet"]) == 2, name
            err = capsys.readouterr().err
            assert name in err and expect in err, (name, err)
    for args, expect in ((["--start", "1.0", "--end", "0.5"], "--end 0.5 s must be after --start 1 s"),
                         (["--start", "-1"], "--start must be a non-negative"),
                         (["--start", "5"], "outside the clip")):
        assert main(["export", str(run), "--motion", str(files["bvh"]), *args, "--out", str(tmp_path / "x.gif"),
                     "--quiet"]) == 2
        assert expect in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == work  # nothing written, no temporary files
