"""Your own photo from the window: the footage panel prepares it (mediapipe in its environment),
shows its steps in a progress bar, the report and its picture, and "Train on it" stops the running training (checkpoint saved,
lock released) and trains on the prepared scene in a run folder of its own; a missing file is a
message in the panel and nothing changes."""

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
SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"

SCRIPT = textwrap.dedent("""
    import json, sys, time
    sys.path.insert(0, {root!r})
    sys.path.insert(0, {root!r} + "/tests")
    from app.studio.window import run_studio
    from reconstruct.data.prepare import FitConfig
    from studio_driver import tiny_config

    out, tmp = {out!r}, {tmp!r}
    result = {{}}
    st = {{"phase": 0}}

    def script(app):
        fc, s = app.footage, app.status
        p = st["phase"]
        if p == 0 and s.step >= 2:
            fc.scenes_root, fc.runs_root = tmp + "/scenes", tmp + "/runs"
            fc.fit_config = FitConfig(keypoint_iters=200, silhouette_iters=30)
            fc.state.source = tmp + "/no_such_photo.png"
            result["missing_started"] = fc.prepare()
            result["missing_message"] = fc.state.message
            fc.state.source, fc.state.masks = {photo!r}, tmp + "/no_such_masks"
            result["missing_masks_started"] = fc.prepare()
            result["missing_masks_message"] = fc.state.message
            fc.state.masks = ""
            fc.state.source = {photo!r}
            result["started"] = fc.prepare()
            result["first_scene"] = app.scene.name
            st["phase"] = 1
        elif p == 1 and fc.busy:
            step = fc.state.current_step()
            if step is not None:
                stages = result.setdefault("stages", [])
                if step[0] not in stages:
                    stages.append(step[0])
                if step[0] == "keypoints" and "bar_shot" not in result:
                    result["bar_shot"] = True
                    app.request_screenshot(out + "_progress.png")
        elif p == 1 and not fc.busy:
            result["scene_folder"] = fc.state.scene_folder
            result["message"] = fc.state.message
            result["report_image"] = fc.state.report_image
            result["people_image"] = fc.state.people_image
            result["report_text"] = bool(fc.state.report_text)
            if fc.state.scene_folder is None:
                app.close()
                return
            app.request_screenshot(out + "_report.png")
            fc.train_on()
            st["phase"] = 2
        elif p == 2 and not fc.busy and app.scene.name != result["first_scene"] and s.step >= 2:
            result["second_scene"] = app.scene.name
            result["second_steps"] = s.step
            result["val_kind"] = app.trainer.trainer.val_kind
            app.close()
        result["phase"] = st["phase"]

    rc = run_studio({scene!r}, tmp + "/run0", config=tiny_config(), size=(900, 700), max_frames=20000,
                    script=script, idle_fps=30, progress=False)
    result["rc"] = rc
    json.dump(result, open(out + ".json", "w"))
""")


@pytest.mark.gl
def test_prepare_a_photo_and_train_on_it_from_the_window(tmp_path):
    from PIL import Image

    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    assert shutil.which("xvfb-run"), "xvfb-run is missing (scripts/bootstrap.sh installs xvfb)"
    scene = build_synthetic_scene(SyntheticConfig(seed=0, num_frames=1, image_size=192, num_eval_azimuths=1,
                                                  eval_frames=1, texture_size=128), progress=False)
    photo = tmp_path / "me.png"
    f = scene.frames[0]
    Image.fromarray((np.clip(f.image + (1 - f.mask[..., None]) * 0.85, 0, 1) * 255).astype(np.uint8)).save(photo)
    out = str(tmp_path / "footage")
    script = tmp_path / "footage_run.py"
    script.write_text(SCRIPT.format(root=str(ROOT), out=out, tmp=str(tmp_path), photo=str(photo), scene=SCENE))
    proc = subprocess.run(["xvfb-run", "-a", sys.executable, str(script)], capture_output=True, text=True,
                          check=False, timeout=600, cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    r = json.loads(Path(out + ".json").read_text())
    assert r["rc"] == 0 and r["missing_started"] is False and "no such file" in r["missing_message"], r
    assert r["missing_masks_started"] is False and "no_such_masks: no such mask" in r["missing_masks_message"], r
    assert r["started"] and r["scene_folder"], (r["message"], r)
    # the bar followed prepare's steps (the fit's at least; the detector's may pass within a frame)
    assert {"keypoints", "silhouette"} <= set(r.get("stages", [])), r.get("stages")
    assert Path(out + "_progress.png").is_file()
    assert Path(r["report_image"]).is_file() and r["report_text"]
    assert r["people_image"] is None  # one person: no picture of who is who
    assert r["phase"] == 2 and r["second_steps"] >= 2 and r["val_kind"] == "training-view fit", r
    # the first run was saved and its lock released; the second trains in its own run folder
    assert (tmp_path / "run0" / "checkpoint.pt").is_file() and (tmp_path / "run0" / ".lock").read_text() == ""
    runs = list((tmp_path / "runs").iterdir())
    assert len(runs) == 1 and json.loads((runs[0] / "run.json").read_text())["scene"] == r["scene_folder"]
    assert Image.open(out + "_report.png").size == (900, 700)
