"""Headless export: orbit / pose videos (.mp4, .gif), screenshots, atomic writes, the CLI."""

from __future__ import annotations

import os

import imageio.v3 as iio
import numpy as np
import pytest
from tiny_runs import TINY_SCENE, train_tiny


@pytest.fixture
def session(tiny_scene, tiny_config):
    """A trained avatar (``TrainedAvatar``) to export."""
    from reconstruct.train.trainer import Trainer

    t = Trainer(tiny_scene, tiny_config)
    for _ in range(3):
        t.step()
    return t.avatar()


def _frames(path):
    return iio.imread(path, index=None)


def _hidden_files(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_orbit_mp4_and_gif(session, tmp_path):
    from app.export import export_orbit

    for suffix in ("mp4", "gif"):
        out = export_orbit(session, tmp_path / f"orbit.{suffix}", frames=6, size=64, fps=12, progress=False)
        assert out == tmp_path / f"orbit.{suffix}" and out.is_file()
        frames = _frames(out)
        assert frames.shape[:3] == (6, 64, 64), (suffix, frames.shape)
        assert frames[..., :3].max() > 40, "all background"
        lit = (frames[..., :3].max(-1) > 20).mean(axis=(1, 2))
        assert np.all(lit > 0.03), lit  # the body is in every view
        diffs = [np.abs(frames[k].astype(int) - frames[k + 1].astype(int)).mean() for k in range(5)]
        assert min(diffs) > 0.5, diffs  # the orbit moves
    assert iio.immeta(tmp_path / "orbit.gif")["loop"] == 0
    assert _hidden_files(tmp_path) == []


def test_orbit_body_is_framed(session, tmp_path):
    from app.export import export_orbit

    frames = _frames(export_orbit(session, tmp_path / "o.gif", frames=4, size=64, elevation=0.0, progress=False))
    rows = np.nonzero((frames[..., :3].max(-1) > 20).any(axis=(0, 2)))[0]
    height = (rows.max() - rows.min() + 1) / 64
    assert 0.6 < height < 0.95, height


def test_poses_gif_has_one_frame_per_pose(session, tmp_path):
    from app.export import export_poses

    n = len(session.scene.frames)
    out = export_poses(session, tmp_path / "poses.gif", size=48, progress=False)
    frames = _frames(out)
    assert frames.shape[0] == n and frames.shape[1:3] == (48, 48)
    assert frames[..., :3].max() > 40
    # another scene object with the same body: posed through the body model, same images
    import dataclasses

    other = dataclasses.replace(session.scene, name="copy")
    frames2 = _frames(export_poses(session, tmp_path / "poses2.gif", scene=other, size=48, progress=False))
    assert frames2.shape == frames.shape
    assert np.abs(frames2.astype(int) - frames.astype(int)).mean() < 1.0


def test_screenshot_png(session, tmp_path):
    from app.export import export_screenshot

    img = iio.imread(export_screenshot(session, tmp_path / "shot.png", size=40))
    assert img.shape == (40, 40, 3) and img.max() > 40


def test_bad_destinations_are_refused_before_rendering(session, tmp_path, monkeypatch):
    import app.export as export

    def no_render(*a, **k):
        raise AssertionError("rendered before checking the destination")

    monkeypatch.setattr(export, "_Renderer", no_render)
    with pytest.raises(ValueError, match=r"'\.avi'.*\.mp4.*\.gif"):
        export.export_orbit(session, tmp_path / "o.avi", frames=2, size=32, progress=False)
    with pytest.raises(ValueError, match=r"'\.gif'"):
        export.export_screenshot(session, tmp_path / "o.gif")
    missing = tmp_path / "no" / "such" / "o.gif"
    with pytest.raises(OSError, match="does not exist"):
        export.export_orbit(session, missing, frames=2, size=32, progress=False)
    assert not missing.parent.exists()
    with pytest.raises(ValueError, match="even frame size"):
        export.export_orbit(session, tmp_path / "o.mp4", frames=2, size=33, progress=False)
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        try:
            with pytest.raises(ValueError, match="not writable"):
                export.export_orbit(session, locked / "o.gif", frames=2, size=32, progress=False)
        finally:
            locked.chmod(0o700)
    assert sorted(p.name for p in tmp_path.iterdir()) == (["locked"] if os.geteuid() != 0 else [])


@pytest.mark.parametrize("suffix", ["gif", "mp4"])
def test_failing_writer_leaves_target_untouched(session, tmp_path, monkeypatch, suffix):
    import app.export as export

    target = tmp_path / f"o.{suffix}"
    target.write_bytes(b"previous")
    calls = {"n": 0}
    real_render = export._render

    def failing_render(*a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise RuntimeError("boom mid-way")
        return real_render(*a, **k)

    monkeypatch.setattr(export, "_render", failing_render)
    with pytest.raises(RuntimeError, match="boom"):
        export.export_orbit(session, target, frames=5, size=32, progress=False)
    assert calls["n"] == 3
    assert target.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]  # no temporary file left


def test_cli_export(tmp_path, capsys):
    from app.cli import main

    run = tmp_path / "run"
    train_tiny(run)
    capsys.readouterr()
    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}

    assert main(["export", str(run), "--orbit", "4", "--out", str(tmp_path / "o.gif"), "--size", "48", "--quiet"]) == 0
    assert _frames(tmp_path / "o.gif").shape[:3] == (4, 48, 48)
    assert main(["export", str(run), "--poses", TINY_SCENE, "--out", str(tmp_path / "p.gif"), "--size", "32",
                 "--quiet"]) == 0
    assert _frames(tmp_path / "p.gif").shape[0] == 3
    capsys.readouterr()

    assert main(["export", str(tmp_path / "nope"), "--orbit", "4", "--out", str(tmp_path / "x.gif")]) == 2
    assert "not a training run" in capsys.readouterr().err
    assert main(["export", str(run), "--orbit", "4", "--out", str(tmp_path / "missing" / "x.gif")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["export", str(run), "--orbit", "4", "--out", str(tmp_path / "x.webm")]) == 2
    assert "'.webm'" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # --orbit and --poses are mutually exclusive, one is required
        main(["export", str(run), "--orbit", "4", "--poses", TINY_SCENE, "--out", str(tmp_path / "x.gif")])
    with pytest.raises(SystemExit):
        main(["export", str(run), "--out", str(tmp_path / "x.gif")])
    capsys.readouterr()
    assert {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == before  # the run folder is untouched
    assert not (tmp_path / "x.gif").exists() and not (tmp_path / "missing").exists()


def test_trained_avatar_exports_mp4_and_gif_with_the_right_frames(tmp_path, capsys):
    """A briefly trained run (a checkpoint after some steps) exported from the command line: an orbit
    as mp4 and a novel walk cycle as gif, reopened and checked for frame count, size and content."""
    from app.cli import main

    scene = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"
    run = tmp_path / "run"
    assert main(["train", "--scene", scene, "--out", str(run), "--iters", "20", "--gaussian-res", "48", "--hidden",
                 "32", "--quiet", "--set", "crop_margin=4"]) == 0
    assert (run / "checkpoint.pt").is_file()
    assert main(["export", str(run), "--orbit", "10", "--out", str(tmp_path / "orbit.mp4"), "--size", "96",
                 "--fps", "10", "--quiet"]) == 0
    assert main(["export", str(run), "--novel", "walk", "--frames", "8", "--out", str(tmp_path / "walk.gif"),
                 "--size", "80", "--fps", "8", "--quiet"]) == 0
    assert main(["export", str(run), "--novel", "arms_up", "--frames", "6", "--out", str(tmp_path / "up.mp4"),
                 "--size", "64", "--quiet"]) == 0
    capsys.readouterr()
    orbit = iio.imread(tmp_path / "orbit.mp4", index=None, plugin="pyav")
    assert orbit.shape == (10, 96, 96, 3), orbit.shape
    meta = iio.immeta(tmp_path / "orbit.mp4", plugin="pyav")
    assert meta["fps"] == pytest.approx(10.0)
    walk = _frames(tmp_path / "walk.gif")
    assert walk.shape[:3] == (8, 80, 80), walk.shape
    assert iio.immeta(tmp_path / "walk.gif")["duration"] == pytest.approx(125, abs=10)  # ms per frame at 8 fps
    up = iio.imread(tmp_path / "up.mp4", index=None, plugin="pyav")
    assert up.shape[:3] == (6, 64, 64)
    for frames in (orbit, walk[..., :3], up):
        assert (frames.max(-1) > 40).mean(axis=(1, 2)).min() > 0.02  # the avatar is in every frame
    # the walk moves: consecutive frames differ; arms up: the top rows fill as the arms rise
    assert min(np.abs(walk[k].astype(int) - walk[k + 1].astype(int)).mean() for k in range(7)) > 0.1
    assert main(["export", str(run), "--novel", "moonwalk", "--out", str(tmp_path / "m.gif")]) == 2
    assert "walk, arms_up" in capsys.readouterr().err
    assert not (tmp_path / "m.gif").exists()
