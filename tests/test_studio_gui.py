"""The studio driven by real input: an Xvfb server, the program in a subprocess, and xdotool moving
and clicking the mouse on widgets whose rectangles the program reports (tests/studio_driver.py).

Checks: the Pause button pauses training; dragging the Stage II canonical:observation slider
changes the setting handed to the trainer; dragging the pose scrubber moves the trainer's
published frame; choosing the visibility map in the mode combo changes the mode and the screenshot
turns to the paper's seen/unseen colours; Start Stage II either starts it or says why not; closing
the window saves a checkpoint into the run folder."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from studio_window import studio_in_xvfb

SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"
SEEN_RGB8 = (236, 166, 128)
UNSEEN_RGB8 = (39, 131, 177)

pytestmark = pytest.mark.gl


def _colour_share(img: np.ndarray, rgb, tol=40) -> float:
    return float((np.abs(img - np.asarray(rgb)).max(-1) < tol).mean())


def test_studio_driven_by_real_input(tmp_path):
    with studio_in_xvfb(tmp_path, SCENE) as gui:
        out, run = gui.out, gui.run
        gui.wait("training", lambda s: s["step"] >= 2 and s["snapshot"]["n"] > 0, timeout=180)
        t0 = time.time()
        while not {"pause", "canonical_ratio", "frame", "mode"} <= set(gui.rects()) and time.time() - t0 < 30:
            time.sleep(0.1)
        gui.attach()

        # Pause (a button)
        gui.click("pause")
        st = gui.wait("pause", lambda s: s["controls"]["paused"])
        step_paused = st["step"]

        # Stage II canonical:observation slider (0.5 by default) dragged to the right
        before = st["controls"]["stage2"]["canonical_ratio"]
        assert before == pytest.approx(0.5)
        gui.drag_slider("canonical_ratio", 0.5, 0.9)
        st = gui.wait("canonical ratio", lambda s: s["controls"]["stage2"]["canonical_ratio"] > 0.75)
        assert st["controls"]["stage2_version"] >= 1
        assert st["controls"]["stage2"]["given_view_ratio"] == pytest.approx(0.5)  # the other slider untouched

        # the pose scrubber to the last frame: the trainer publishes that frame, the view draws it
        n = st["num_frames"]
        assert st["controls"]["frame_index"] == 0
        gui.drag_slider("frame", 0.1, 0.98)
        st = gui.wait("scrubbed frame", lambda s: s["controls"]["frame_index"] == n - 1
                      and s["snapshot"]["frame_index"] == n - 1 and s["drawn"] and s["drawn"][0] == s["snapshot"]["version"])
        rgb = gui.screenshot("rgb")

        # the visibility map through the mode combo
        gui.click("mode")
        t0 = time.time()
        while "mode_visibility" not in gui.rects() and time.time() - t0 < 10:
            time.sleep(0.1)
        gui.click("mode_visibility")
        gui.wait("visibility mode", lambda s: s["mode"] == "visibility")
        time.sleep(0.5)
        vis = gui.screenshot("vis")

        # Start Stage II: it starts, or the panel says why not; Stage I goes on either way
        gui.click("start_stage2")
        st = gui.wait("stage II answer", lambda s: s["stage"] == 2 or bool(s["stage2_message"]))
        assert st["error"] is None
        assert st["step"] >= step_paused
        gui.quit()
    log = gui.log
    assert gui.app.returncode == 0, log
    assert json.loads(Path(out + ".exit.json").read_text())["rc"] == 0

    # the screenshots: the view between the panel columns
    assert rgb.shape == (800, 1280, 3) and vis.shape == rgb.shape
    centre = (slice(100, 700), slice(340, 940))
    r, v = rgb[centre], vis[centre]
    assert r.std() > 5  # the avatar is in the picture
    vis_share = _colour_share(v, SEEN_RGB8) + _colour_share(v, UNSEEN_RGB8)
    rgb_share = _colour_share(r, SEEN_RGB8) + _colour_share(r, UNSEEN_RGB8)
    assert vis_share > 0.01 and vis_share > 5 * rgb_share, (vis_share, rgb_share)
    assert _colour_share(v, UNSEEN_RGB8) > 0.002  # a front camera leaves some of the body unseen
    assert (np.abs(r - v).max(-1) > 30).mean() > 0.01
    # closing the window saved a checkpoint first
    assert (run / "checkpoint.pt").is_file(), log
    assert "saved" in log
