"""The studio's Pose panel with a motion file (Xvfb, scripted like tests/test_studio.py): a missing,
an unsupported and an empty file are refused with the message in the panel and nothing else lost; a
BVH written by bvhio is read and retargeted in the background and then scrubbed and played like the
built-in sequences (the published snapshot follows); the loaded clip exports as a video."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"

SCRIPT = textwrap.dedent("""
    import json, sys, time
    import numpy as np
    sys.path.insert(0, {root!r})
    sys.path.insert(0, {root!r} + "/tests")
    from app.studio.window import run_studio
    from studio_driver import tiny_config

    out, files = {out!r}, {files!r}
    result = {{"messages": {{}}, "t": {{}}}}
    state = {{"phase": 0, "t0": 0.0}}

    def published(app):
        p = app.trainer.published
        return p[0] if p else None

    def script(app):
        s, m, snap = app.status, app.view.motion, app.latest_snapshot()
        p = state["phase"]
        if p == 0 and s.step >= 2 and len(snap):
            app.set_pose_source("motion")  # nothing open yet: a message, the source unchanged
            result["source_before"] = app.view.pose_source
            result["messages"]["none_open"] = m.message
            app.open_motion(files["missing"])
            state["phase"] = 1
        elif p in (1, 2, 3) and m.job is None:
            name = ("missing", "xscale", "empty")[p - 1]
            result["messages"][name] = m.message
            result.setdefault("sources_after_errors", []).append(app.view.pose_source)
            if p < 3:
                app.open_motion(files[("xscale", "empty")[p - 1]])
            else:
                state["t0"] = time.perf_counter()
                app.open_motion(files["good"])
            state["phase"] = p + 1
        elif p == 4 and m.job is None:
            result["t"]["open"] = time.perf_counter() - state["t0"]
            result["loaded"] = m.loaded is not None and m.loaded.name
            result["message_after_good"] = m.message
            result["pose_source"] = app.view.pose_source
            result["num_pose_frames"] = app.num_pose_frames
            result["notes"] = list(m.loaded.notes) if m.loaded else []
            app.set_pose_frame(0)
            state["phase"] = 5
        elif p == 5:
            key = published(app)
            if key and key[2] == m.loaded.key and key[3] == 0 and app.last_drawn_snapshot \\
                    and app.last_drawn_snapshot[0] == snap.version:
                result["frame0_version"] = snap.version
                state["means0"] = snap.means.copy()
                state["mid"] = app.num_pose_frames // 2
                app.set_pose_frame(state["mid"])
                state["phase"] = 6
        elif p == 6:
            key = published(app)
            if key and key[2] == m.loaded.key and key[3] == state["mid"] \\
                    and snap.version > result["frame0_version"]:
                d = np.linalg.norm(snap.means - state["means0"], axis=1)
                result["moved_max"] = float(d.max())
                result["published_mid"] = list(key)
                app.request_screenshot(out + "_motion_panel.png")
                # the loaded clip as a video from the export panel
                e = app.export.settings
                e.kind, e.size, e.out = "motion", 64, out + "_motion.gif"
                app.start_export()
                state["phase"] = 7
        elif p == 7 and app.export.job.done:
            result["export"] = str(app.export.job.result) if app.export.job.result else app.export.job.error
            result["export_total"] = app.export.job.total
            app.open_motion(files["empty"])  # a failure after a good file: the good one stays
            state["phase"] = 8
        elif p == 8 and m.job is None:
            result["kept_after_error"] = m.loaded is not None and m.loaded.name
            result["source_after_late_error"] = app.view.pose_source
            result["late_message"] = m.message
            app.toggle_play()
            state["play_from"] = app.view.novel_index
            state["phase"] = 9
            state["t0"] = time.perf_counter()
        elif p == 9 and time.perf_counter() - state["t0"] > 1.0:
            result["played_frames"] = (app.view.novel_index - state["play_from"]) % app.num_pose_frames
            result["error"] = s.error
            app.close()
        result["phase"] = state["phase"]

    rc = run_studio({scene!r}, None, config=tiny_config(), size=(1280, 800), max_frames=4000, script=script,
                    idle_fps=30, progress=False)
    result["rc"] = rc
    json.dump(result, open(out + ".json", "w"))
""")


@pytest.mark.gl
def test_pose_panel_opens_scrubs_and_plays_a_motion_file(tmp_path):
    from motion_files import write_test_bvh

    assert shutil.which("xvfb-run"), "xvfb-run is missing (scripts/bootstrap.sh installs xvfb)"
    good = write_test_bvh(tmp_path / "arms.bvh", frames=40)
    text = good.read_text()
    xscale = tmp_path / "xscale.bvh"
    xscale.write_text(text.replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Xscale Xrotation Yrotation", 1))
    empty = tmp_path / "empty.bvh"
    head = text[: text.index("MOTION")]
    empty.write_text(head + "MOTION\nFrames: 0\nFrame Time: 0.033333\n")
    files = {"missing": str(tmp_path / "nope.bvh"), "xscale": str(xscale), "empty": str(empty), "good": str(good)}
    out = str(tmp_path / "studio")
    script = tmp_path / "studio_motion.py"
    script.write_text(SCRIPT.format(root=str(ROOT), out=out, files=files, scene=SCENE))
    proc = subprocess.run(["xvfb-run", "-a", sys.executable, str(script)], capture_output=True, text=True, check=False,
                          timeout=400, cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    r = json.loads(Path(out + ".json").read_text())
    print("\n[studio motion]", json.dumps({k: r[k] for k in ("messages", "t", "num_pose_frames", "moved_max",
                                                              "played_frames")}, indent=1))
    assert r["rc"] == 0 and r["phase"] == 9 and r["error"] is None, r
    msgs = r["messages"]
    assert r["source_before"] == "video" and "no motion file open" in msgs["none_open"]
    assert "nope.bvh" in msgs["missing"] and "no such motion file" in msgs["missing"]
    assert "xscale.bvh" in msgs["xscale"] and "Xscale" in msgs["xscale"]
    assert "empty.bvh" in msgs["empty"] and "empty" in msgs["empty"].lower()
    assert r["sources_after_errors"] == ["video"] * 3  # nothing else changed
    # the good file: shown at once, 40 frames at 30 fps resampled to the scene's frame rate
    assert r["loaded"] == "arms.bvh" and r["message_after_good"] is None and r["pose_source"] == "motion"
    assert r["num_pose_frames"] >= 10
    assert any("LeftHandIndex1" in n and "dropped" in n for n in r["notes"])
    assert r["moved_max"] > 0.2, r  # the arms came down: the published Gaussians moved
    assert r["export"] == out + "_motion.gif" and r["export_total"] == r["num_pose_frames"]
    import imageio.v3 as iio

    assert iio.imread(out + "_motion.gif", index=None).shape[0] == r["num_pose_frames"]
    # a later failure keeps what was shown
    assert r["kept_after_error"] == "arms.bvh" and r["source_after_late_error"] == "motion"
    assert "empty.bvh" in r["late_message"]
    assert r["played_frames"] >= 3  # playback advanced through the clip
    from PIL import Image

    shot = np.asarray(Image.open(out + "_motion_panel.png").convert("RGB"))
    assert shot.shape == (800, 1280, 3) and shot.std() > 5
