"""The same SplatRenderer drawing into a glfw window's context (GLX under Xvfb) and into EGL.

The window runs in a subprocess: a process must create its GLX window context before any EGL
context (DESIGN.md), and the test process already holds an EGL one."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.gl

SCRIPT = textwrap.dedent("""
    import sys
    sys.path.insert(0, {root!r})
    import numpy as np
    from imgui_bundle import imgui  # noqa: F401  (the studio imports imgui-bundle before glfw)
    import glfw
    import moderngl
    if not glfw.init():
        raise SystemExit("glfw.init failed")
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
    win = glfw.create_window(160, 120, "splats", None, None)
    glfw.make_context_current(win)
    ctx = moderngl.create_context()
    from benchmarks.renderer import body_like_snapshot, framing_camera
    from renderer.framebuffer import read_framebuffer
    from renderer.splat_renderer import SplatRenderer
    r = SplatRenderer(ctx)
    r.set_snapshot(body_like_snapshot(4000, seed=1))
    cam = framing_camera(120, azimuth=20).scaled(160, 120)
    fw, fh = glfw.get_framebuffer_size(win)
    assert (fw, fh) == (160, 120), (fw, fh)
    assert r.render(cam, target=ctx.screen, background=(1, 1, 1)) is None
    screen = read_framebuffer(ctx.screen, 160, 120, "u1", np.float32)
    offscreen = r.render(cam, background=(1, 1, 1))  # an FBO in the window's context
    # overlays into the window's default framebuffer (its own depth buffer) and into an FBO
    import dataclasses
    from renderer.overlay import OverlayStyle
    box_v = np.array([[x, y, z] for x in (-0.2, 0.2) for y in (-0.15, 0.15) for z in (0.9, 1.4)], np.float32)
    box_f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)
    r.set_snapshot(dataclasses.replace(body_like_snapshot(4000, seed=1), mesh_vertices=box_v, mesh_faces=box_f))
    style = OverlayStyle(mesh="wireframe", skeleton=True)
    r.render(cam, target=ctx.screen, background=(1, 1, 1), overlay=style)
    screen_overlay = read_framebuffer(ctx.screen, 160, 120, "u1", np.float32)
    offscreen_overlay = r.render(cam, background=(1, 1, 1), overlay=style)
    glfw.swap_buffers(win)
    r.release()
    np.savez({out!r}, screen=screen, offscreen=offscreen, screen_overlay=screen_overlay,
             offscreen_overlay=offscreen_overlay)
    glfw.terminate()
""")


def test_window_context_draws_the_same_image(tmp_path):
    from benchmarks.renderer import body_like_snapshot, framing_camera
    from renderer.gl_context import create_offscreen_context
    from renderer.splat_renderer import SplatRenderer

    assert shutil.which("xvfb-run"), "xvfb-run is missing (scripts/bootstrap.sh installs xvfb)"

    out = tmp_path / "window.npz"
    script = tmp_path / "window.py"
    script.write_text(SCRIPT.format(root=str(ROOT), out=str(out)))
    proc = subprocess.run(["xvfb-run", "-a", sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    data = np.load(out)
    screen, window_offscreen = data["screen"], data["offscreen"]

    ctx = create_offscreen_context()
    try:
        r = SplatRenderer(ctx)
        r.set_snapshot(body_like_snapshot(4000, seed=1))
        egl = r.render(framing_camera(120, azimuth=20).scaled(160, 120), background=(1, 1, 1))
        r.release()
    finally:
        ctx.release()

    assert (egl[..., 3] > 0.5).sum() > 1000  # the body is in the picture
    np.testing.assert_allclose(window_offscreen, egl, atol=1e-5)  # same renderer, same float target
    # the window's 8-bit framebuffer rounds at every blend: close, not equal
    mse = float(np.mean((screen[..., :3] - egl[..., :3]) ** 2))
    print(f"window 8-bit vs EGL float: PSNR {10 * math.log10(1 / mse):.1f} dB")
    assert 10 * math.log10(1 / mse) >= 40.0

    so, oo = data["screen_overlay"], data["offscreen_overlay"]
    drawn = np.abs(oo[..., :3] - window_offscreen[..., :3]).max(-1) > 0.1
    assert drawn.sum() > 100  # wireframe box and skeleton are there
    agree = np.abs(so[..., :3] - oo[..., :3]).max(-1) < 0.05
    assert agree[drawn].mean() > 0.97
