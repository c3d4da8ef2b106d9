"""The studio under real input, for the window tests: an Xvfb server, the program in a subprocess
(tests/studio_driver.py writes its state, widget rectangles, screenshots and arrays to files next to
``out``), and xdotool moving and clicking the mouse and typing keys.

    with studio_in_xvfb(tmp_path, SCENE) as win:
        win.wait("training", lambda s: s["step"] >= 2, timeout=180)
        win.attach()
        win.click("pause")
        ...
        win.quit()
    assert win.app.returncode == 0, win.log
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def start_xvfb():
    r, w = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(w), "-screen", "0", "1600x1000x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    with os.fdopen(r) as f:
        number = f.readline().strip()
    assert number, "Xvfb did not report a display"
    return proc, f":{number}"


class StudioWindow:
    """The driver's files and xdotool. ``wait_timeout``: how long ``wait`` waits by default;
    ``move_pause``: seconds after each mouse move (for the window to draw a frame)."""

    def __init__(self, out: str, run: Path, env: dict, app: subprocess.Popen, wait_timeout: float = 90.0,
                 move_pause: float = 0.2):
        self.out, self.run, self.env, self.app = out, run, env, app
        self.wait_timeout, self.move_pause = wait_timeout, move_pause
        self.wid = None
        self.log = ""

    # ----- what the program reports ----------------------------------------------------------
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

    def wait(self, what, cond, timeout: float | None = None) -> dict:
        timeout = self.wait_timeout if timeout is None else timeout
        t0 = time.time()
        while time.time() - t0 < timeout:
            st = self.state()
            if st and cond(st):
                return st
            time.sleep(0.1)
        raise AssertionError(f"timed out waiting for {what}; last state {self.state()}")

    def wait_rect(self, name, timeout=20.0) -> list:
        t0 = time.time()
        while name not in self.rects() and time.time() - t0 < timeout:
            time.sleep(0.1)
        return self.rects()[name]

    def file(self, kind, name, timeout=30.0) -> Path:
        """Ask the program for a screenshot (``shot``) or arrays (``dump``) and wait for the file."""
        path = Path(f"{self.out}.{name}.{'png' if kind == 'shot' else 'npz'}")
        path.unlink(missing_ok=True)
        Path(f"{self.out}.{kind}_{name}.req").touch()
        t0 = time.time()
        while not path.exists() and time.time() - t0 < timeout:
            time.sleep(0.1)
        assert path.exists(), f"no {path}"
        return path

    def screenshot(self, name) -> np.ndarray:
        from PIL import Image

        return np.asarray(Image.open(self.file("shot", name)).convert("RGB"), np.int32)

    def arrays(self, name) -> dict:
        with np.load(self.file("dump", name)) as z:
            return {k: z[k] for k in z.files}

    # ----- input -------------------------------------------------------------------------------
    def attach(self) -> None:
        """Find the studio's window on the display (input goes to it)."""
        wid = subprocess.run(["xdotool", "search", "--sync", "--name", "WonderHuman Studio"], env=self.env,
                             capture_output=True, text=True, timeout=30).stdout.split()
        assert wid, "no studio window on the display"
        self.wid = wid[0]

    def xdo(self, *args):
        subprocess.run(["xdotool", *map(str, args)], env=self.env, check=True, timeout=20)

    def frames(self, n: int = 2, timeout: float = 10.0) -> None:
        """Wait until the window has drawn ``n`` more frames (at most ``timeout`` s). Input reaches
        the GUI a frame at a time; on a loaded machine (5 frames/s) a frame outlasts the fixed
        pauses, and a press and its release could land in one frame, or a click on a popup before
        the popup's frame."""
        start = self.state().get("frame")
        if start is None:
            return
        t0 = time.time()
        while time.time() - t0 < timeout:
            now = self.state().get("frame")
            if now is not None and now >= start + n:
                return
            time.sleep(0.02)

    def move(self, x, y):
        self.xdo("mousemove", "--window", self.wid, int(round(x)), int(round(y)))
        time.sleep(self.move_pause)
        self.frames()

    def click(self, name):
        x0, y0, x1, y1 = self.wait_rect(name)
        self.move(0.5 * (x0 + x1), 0.5 * (y0 + y1))
        self.xdo("mousedown", 1)
        time.sleep(0.2)
        self.frames()
        self.xdo("mouseup", 1)
        time.sleep(0.2)
        self.frames()

    def drag(self, a, b, steps=6):
        """A left-button drag from window point ``a`` to ``b`` in ``steps`` moves."""
        self.move(*a)
        self.xdo("mousedown", 1)
        time.sleep(0.2)
        for k in range(1, steps + 1):
            self.move(a[0] + (b[0] - a[0]) * k / steps, a[1] + (b[1] - a[1]) * k / steps)
        self.xdo("mouseup", 1)
        time.sleep(0.2)

    def drag_slider(self, name, frac_from, frac_to, steps=8):
        """A drag along the middle of widget ``name`` between two fractions of its width."""
        x0, y0, x1, y1 = self.rects()[name]
        y = 0.5 * (y0 + y1)
        self.drag((x0 + frac_from * (x1 - x0), y), (x0 + frac_to * (x1 - x0), y), steps)

    def key(self, keys):
        """A chord as a person types it: the modifiers held down for a moment around the key (an
        instant ``xdotool key ctrl+z`` can reach the window's frames with the key and its modifier
        in different frames)."""
        *mods, key = keys.split("+")
        for m in mods:
            self.xdo("keydown", m)
        time.sleep(0.2)
        self.frames()
        self.xdo("key", key)
        time.sleep(0.2)
        self.frames()
        for m in reversed(mods):
            self.xdo("keyup", m)
        time.sleep(0.2)
        self.frames()

    def quit(self, timeout=120) -> None:
        Path(self.out + ".quit").touch()
        self.app.wait(timeout=timeout)


@contextmanager
def studio_in_xvfb(tmp_path: Path, scene: str, wait_timeout: float = 90.0, move_pause: float = 0.2):
    """The studio on ``scene`` with its run folder at ``tmp_path/run``, on a fresh Xvfb display.
    A failure inside the block is reported with the program's output; the program is killed if
    it is still running, and ``win.log`` holds its output afterwards."""
    for tool in ("Xvfb", "xdotool"):
        assert shutil.which(tool), f"{tool} is missing (scripts/bootstrap.sh installs xvfb and xdotool)"
    xvfb, display = start_xvfb()
    out = str(tmp_path / "gui")
    run = tmp_path / "run"
    env = {**os.environ, "DISPLAY": display}
    app = subprocess.Popen([sys.executable, str(ROOT / "tests" / "studio_driver.py"), out, scene, str(run)], env=env,
                           cwd=str(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    win = StudioWindow(out, run, env, app, wait_timeout, move_pause)
    try:
        yield win
    except (AssertionError, subprocess.SubprocessError) as exc:
        if app.poll() is None:
            app.kill()
        raise AssertionError(f"{exc}\n--- studio output ---\n{app.stdout.read()[-3000:]}") from None
    finally:
        if app.poll() is None:
            app.kill()
        win.log = app.stdout.read() if app.stdout and not app.stdout.closed else ""
        xvfb.terminate()
        xvfb.wait(10)
