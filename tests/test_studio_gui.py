"""The studio driven by real input: an Xvfb server, the program in a subprocess, and xdotool moving
and clicking the mouse on widgets whose rectangles the program reports (tests/studio_driver.py).

Checks: the Pause button pauses training; dragging the Stage II canonical:observation slider
changes the setting handed to the trainer; dragging the pose scrubber moves the trainer's
published frame; choosing the visibility map in the mode combo changes the mode and the screenshot
turns to the paper's seen/unseen colours; Start Stage II either starts it or says why not; closing
the window saves a checkpoint into the run folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"
SEEN_RGB8 = (236, 166, 128)
UNSEEN_RGB8 = (39, 131, 177)

pytestmark = pytest.mark.gl


def _start_xvfb():
    r, w = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(w), "-screen", "0", "1600x1000x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    with os.fdopen(r) as f:
        number = f.readline().strip()
    assert number, "Xvfb did not report a display"
    return proc, f":{number}"


class Gui:
    def __init__(self, out: str, env: dict):
        self.out = out
        self.env = env
        self.wid = None

    def state(self) -> dict:
        try:
            return json.loads(Path(self.out + ".state.json").read_text())
        except (OSError, ValueError):
            return {}

    def rects(self) -> dict:
        try:
            return json.loads(Path(self.out + ".rects.json").read_text())["rects"]
        except (OSError, ValueError, KeyError):
            return {}

    def wait(self, what, cond, timeout=90.0):
        t0 = time.time()
        while time.time() - t0 < timeout:
            st = self.state()
            if st and cond(st):
                return st
            time.sleep(0.1)
        raise AssertionError(f"timed out waiting for {what}; last state {self.state()}")

    def xdo(self, *args):
        subprocess.run(["xdotool", *map(str, args)], env=self.env, check=True, timeout=20)

    def move(self, x, y):
        self.xdo("mousemove", "--window", self.wid, int(round(x)), int(round(y)))
        time.sleep(0.2)

    def click(self, name):
        x0, y0, x1, y1 = self.rects()[name]
        self.move(0.5 * (x0 + x1), 0.5 * (y0 + y1))
        self.xdo("mousedown", 1)
        time.sleep(0.2)
        self.xdo("mouseup", 1)
        time.sleep(0.2)

    def drag(self, name, frac_from, frac_to, steps=8):
        x0, y0, x1, y1 = self.rects()[name]
        y = 0.5 * (y0 + y1)
        xa, xb = x0 + frac_from * (x1 - x0), x0 + frac_to * (x1 - x0)
        self.move(xa, y)
        self.xdo("mousedown", 1)
        time.sleep(0.2)
        for k in range(1, steps + 1):
            self.move(xa + (xb - xa) * k / steps, y)
        self.xdo("mouseup", 1)
        time.sleep(0.2)

    def screenshot(self, name) -> np.ndarray:
        from PIL import Image

        path = Path(f"{self.out}.{name}.png")
        Path(f"{self.out}.shot_{name}.req").touch()
        t0 = time.time()
        while not path.exists() and time.time() - t0 < 30:
            time.sleep(0.1)
        assert path.exists(), f"no screenshot {path}"
        return np.asarray(Image.open(path).convert("RGB"), np.int32)


def _colour_share(img: np.ndarray, rgb, tol=40) -> float:
    return float((np.abs(img - np.asarray(rgb)).max(-1) < tol).mean())


def test_studio_driven_by_real_input(tmp_path):
    for tool in ("Xvfb", "xdotool"):
        assert shutil.which(tool), f"{tool} is missing (scripts/bootstrap.sh installs xvfb and xdotool)"
    xvfb, display = _start_xvfb()
    out = str(tmp_path / "gui")
    run = tmp_path / "run"
    env = {**os.environ, "DISPLAY": display}
    app = subprocess.Popen([sys.executable, str(ROOT / "tests" / "studio_driver.py"), out, SCENE, str(run)], env=env,
                           cwd=str(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    gui = Gui(out, env)
    try:
        gui.wait("training", lambda s: s["step"] >= 2 and s["snapshot"]["n"] > 0, timeout=180)
        t0 = time.time()
        while not {"pause", "canonical_ratio", "frame", "mode"} <= set(gui.rects()) and time.time() - t0 < 30:
            time.sleep(0.1)
        wid = subprocess.run(["xdotool", "search", "--sync", "--name", "WonderHuman Studio"], env=env,
                             capture_output=True, text=True, timeout=30).stdout.split()
        assert wid, "no studio window on the display"
        gui.wid = wid[0]

        # Pause (a button)
        gui.click("pause")
        st = gui.wait("pause", lambda s: s["controls"]["paused"])
        step_paused = st["step"]

        # Stage II canonical:observation slider (0.5 by default) dragged to the right
        before = st["controls"]["stage2"]["canonical_ratio"]
        assert before == pytest.approx(0.5)
        gui.drag("canonical_ratio", 0.5, 0.9)
        st = gui.wait("canonical ratio", lambda s: s["controls"]["stage2"]["canonical_ratio"] > 0.75)
        assert st["controls"]["stage2_version"] >= 1
        assert st["controls"]["stage2"]["given_view_ratio"] == pytest.approx(0.5)  # the other slider untouched

        # the pose scrubber to the last frame: the trainer publishes that frame, the view draws it
        n = st["num_frames"]
        assert st["controls"]["frame_index"] == 0
        gui.drag("frame", 0.1, 0.98)
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
        Path(out + ".quit").touch()
        app.wait(timeout=120)
    except AssertionError as exc:
        if app.poll() is None:
            app.kill()
        raise AssertionError(f"{exc}\n--- studio output ---\n{app.stdout.read()[-3000:]}") from None
    finally:
        if app.poll() is None:
            app.kill()
        log = app.stdout.read() if app.stdout and not app.stdout.closed else ""
        xvfb.terminate()
        xvfb.wait(10)
    assert app.returncode == 0, log
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
