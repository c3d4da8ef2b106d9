"""The studio window under Xvfb, driven by a script instead of real input; and the no-display message.

The window runs in a subprocess: a process must create its GLX window context before any EGL
context (DESIGN.md), and the test process may already hold an EGL one."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"

SCRIPT = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {root!r})
    from app.studio.window import run_studio
    from reconstruct.avatar.config import AvatarConfig
    from reconstruct.train.config import Stage1Config

    out = {out!r}
    cfg = Stage1Config(iters=100000, eval_every_seconds=1e9, checkpoint_every_seconds=1e9, crop_margin=4,
                       avatar=AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8,
                                           pose_feature_channels=8, hidden=32))
    result = {{"phases": []}}
    state = {{"phase": 0, "wait": 0}}

    def script(app):
        s, snap = app.status, app.latest_snapshot()
        p = state["phase"]
        if p == 0 and s.step >= 3 and len(snap) and app.frame_count >= 30:
            app.pause(True)
            result["step_before_pause"] = s.step
            state["phase"] = 1
        elif p == 1:
            # the frame scrubber: what the Pose panel's slider does
            app.set_frame(2)
            state["phase"] = 2
        elif p == 2 and s.paused and snap.frame_index == 2 and snap.step == s.step \\
                and app.last_drawn_snapshot and app.last_drawn_snapshot[0] == snap.version:
            result["published_frame"] = snap.frame_index
            app.view.show_gui = False
            app.request_screenshot(out + "_rgb.png")
            state["phase"] = 3
        elif p == 3:
            app.set_mode("visibility")
            app.request_screenshot(out + "_vis.png")
            state["phase"] = 4
        elif p == 4:
            app.view.show_gui = True
            state["phase"] = 5
            state["wait"] = app.frame_count + 5
        elif p == 5 and app.frame_count >= state["wait"]:
            result["step"] = s.step
            result["history"] = len(app.trainer.history())
            result["error"] = s.error
            app.close()
        result["frames"] = app.frame_count + 1
        result["phase"] = state["phase"]

    rc = run_studio({scene!r}, None, config=cfg, size=(320, 240), max_frames=1500, script=script, idle_fps=30,
                    screenshot=out + "_final.png", progress=False)
    result["rc"] = rc
    json.dump(result, open(out + ".json", "w"))
""")


@pytest.mark.gl
def test_studio_window_trains_scrubs_and_switches_modes(tmp_path):
    from PIL import Image

    assert shutil.which("xvfb-run"), "xvfb-run is missing (scripts/bootstrap.sh installs xvfb)"
    out = str(tmp_path / "studio")
    script = tmp_path / "studio_run.py"
    script.write_text(SCRIPT.format(root=str(ROOT), out=out, scene=SCENE))
    proc = subprocess.run(["xvfb-run", "-a", sys.executable, str(script)], capture_output=True, text=True, check=False,
                          timeout=300, cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = json.loads(Path(out + ".json").read_text())
    assert result["rc"] == 0 and result["error"] is None, result
    assert result["phase"] == 5, f"script did not finish: {result}"
    assert result["step"] > 0 and result["history"] > 1
    assert result["published_frame"] == 2  # the slider moved the trainer's published frame
    rgb = np.asarray(Image.open(out + "_rgb.png"), np.float32)
    vis = np.asarray(Image.open(out + "_vis.png"), np.float32)
    final = Image.open(out + "_final.png")
    assert final.size == (320, 240) and rgb.shape == (240, 320, 3)
    assert rgb.std() > 5  # the avatar is in the picture
    changed = np.abs(rgb - vis).max(-1) > 30
    assert changed.sum() > 200, changed.sum()  # the visibility map looks different
    assert not (tmp_path / "imgui.ini").exists()


def test_no_display_prints_one_line_and_fails():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.run([sys.executable, "-m", "app.cli"], capture_output=True, text=True, timeout=120, check=False,
                          cwd=str(ROOT), env=env)
    assert proc.returncode == 1
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1, proc.stdout
    assert "no display" in lines[0] and "wonderhuman-studio demo" in lines[0]
    assert "train" in lines[0] and "export" in lines[0]


EXPORT_SCRIPT = textwrap.dedent("""
    import json, sys, time
    sys.path.insert(0, {root!r})
    sys.path.insert(0, {root!r} + "/tests")
    from app.studio.window import run_studio
    from studio_driver import tiny_config

    out, run = {out!r}, {run!r}
    result = {{}}
    state = {{"phase": 0}}

    def script(app):
        s, ex = app.status, app.export
        p = state["phase"]
        if p == 0 and s.step >= 2 and len(app.latest_snapshot()):
            # an export to a folder that does not exist: refused at once, training goes on
            ex.settings.out = out + "_missing/x.gif"
            result["bad_job"] = app.start_export() is not None
            result["bad_message"] = ex.message
            e = ex.settings
            e.kind, e.frames, e.size, e.fps, e.out = "orbit", 6, 64, 12, out + "_orbit.gif"
            app.start_export()
            result["step_at_export_start"] = s.step
            state["phase"] = 1
        elif p == 1 and ex.job.done:
            result["orbit"] = str(ex.job.result) if ex.job.result else ex.job.error
            result["steps_during_export"] = s.step - result["step_at_export_start"]
            e = ex.settings
            e.kind, e.frames, e.size, e.out = "walk", 5, 64, out + "_walk.mp4"
            app.start_export()
            state["phase"] = 2
        elif p == 2 and ex.job.done:
            result["walk"] = str(ex.job.result) if ex.job.result else ex.job.error
            # a novel pose in the live view
            app.set_pose_source("arms_up")
            app.set_pose_frame(app.num_pose_frames - 1)
            state["phase"] = 3
        elif p == 3:
            published = app.trainer.published
            if published and published[0][2] == "arms_up" and published[0][3] == app.num_pose_frames - 1:
                result["novel_published"] = True
                result["step_before_close"] = s.step
                app.close()  # mid-training: the trainer is not paused
        result["phase"] = state["phase"]

    rc = run_studio({scene!r}, run, config=tiny_config(), size=(320, 240), max_frames=3000, script=script,
                    idle_fps=30, progress=False)
    result["rc"] = rc
    json.dump(result, open(out + ".json", "w"))
""")


@pytest.mark.gl
def test_studio_exports_while_training_and_saves_on_close(tmp_path):
    import imageio.v3 as iio
    import torch

    out, run = str(tmp_path / "studio"), tmp_path / "run"
    script = tmp_path / "studio_export.py"
    script.write_text(EXPORT_SCRIPT.format(root=str(ROOT), out=out, run=str(run), scene=SCENE))
    proc = subprocess.run(["xvfb-run", "-a", sys.executable, str(script)], capture_output=True, text=True, check=False,
                          timeout=300, cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = json.loads(Path(out + ".json").read_text())
    assert result["rc"] == 0 and result["phase"] == 3, result
    # the unwritable path: refused with a message, no job, nothing created
    assert result["bad_job"] is False and "does not exist" in result["bad_message"], result
    assert not Path(out + "_missing").exists()
    # the orbit gif and the novel walk mp4, written while training went on
    assert result["orbit"] == out + "_orbit.gif", result
    assert iio.imread(out + "_orbit.gif", index=None).shape[:3] == (6, 64, 64)
    assert result["walk"] == out + "_walk.mp4", result
    walk = iio.imread(out + "_walk.mp4", index=None, plugin="pyav")
    assert walk.shape[0] == 5 and walk.shape[1:3] == (64, 64)
    assert result["steps_during_export"] >= 1, result  # training did not wait for the export
    assert result["novel_published"]
    # closing the window mid-training saved a checkpoint first
    state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=True)
    assert state["step"] >= result["step_before_close"] >= 2
    assert "saved" in proc.stderr and "checkpoint.pt" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temporary files


@pytest.mark.gl
def test_scene_that_fails_to_load_is_shown_in_the_window(tmp_path):
    from PIL import Image

    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from app.studio.window import run_studio
        sys.exit(run_studio({str(tmp_path / 'no_such_scene')!r}, None, size=(640, 400), max_frames=5,
                            screenshot={str(tmp_path / 'error.png')!r}, progress=False))
    """)
    proc = subprocess.run(["xvfb-run", "-a", sys.executable, "-c", code], capture_output=True, text=True, check=False,
                          timeout=120, cwd=str(tmp_path))
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "could not open the scene" in proc.stderr and "no_such_scene" in proc.stderr
    assert "Traceback" not in proc.stderr
    img = np.asarray(Image.open(tmp_path / "error.png").convert("RGB"), np.int32)
    assert img.shape == (400, 640, 3)
    # the error text is drawn in the window (reddish text over the dark window)
    red = (img[..., 0] > 200) & (img[..., 1] < 160) & (img[..., 2] < 150)
    assert red.sum() > 100, red.sum()


@pytest.mark.gl
def test_a_run_folder_in_use_is_refused_in_the_window(tmp_path):
    """The studio takes the run folder's lock: with another trainer holding it, the window shows
    why and exits 2, and the folder is left as it was."""
    from PIL import Image

    from reconstruct.run_folder import RunFolder

    run = RunFolder(tmp_path / "run")
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from app.studio.window import run_studio
        sys.exit(run_studio({SCENE!r}, {str(run.path)!r}, size=(640, 400), max_frames=5,
                            screenshot={str(tmp_path / 'locked.png')!r}, progress=False))
    """)
    with run.lock():
        before = sorted(p.name for p in run.path.iterdir())
        proc = subprocess.run(["xvfb-run", "-a", sys.executable, "-c", code], capture_output=True, text=True,
                              check=False, timeout=120, cwd=str(tmp_path))
        assert sorted(p.name for p in run.path.iterdir()) == before
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "could not open the run folder" in proc.stderr and f"pid {os.getpid()}" in proc.stderr
    img = np.asarray(Image.open(tmp_path / "locked.png").convert("RGB"), np.int32)
    red = (img[..., 0] > 200) & (img[..., 1] < 160) & (img[..., 2] < 150)
    assert red.sum() > 100, red.sum()
