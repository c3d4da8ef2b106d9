"""The editor in the studio window (issue 22): the selection tools' logic (combine modes, modifier
keys, brush / rectangle / lasso strokes on a cached id image), the renderer's highlight in every
mode, the trainer thread's edit queue (apply, undo bit-exactly, redo, guidance steps, the Stage II
plan), and the window driven by real input under Xvfb (rectangle tool, Erase, Ctrl+Z,
Ctrl+Shift+Z, the highlight in a screenshot)."""

from __future__ import annotations

import json
import time
from types import SimpleNamespace

import numpy as np
import pytest

from app.studio.edit_tools import (
    Stroke,
    StrokeView,
    ToolSettings,
    brush_box,
    combine,
    combine_mode,
    lasso_box,
    rect_box,
)
from reconstruct.edits import selection as S
from studio_window import studio_in_xvfb

ARRAYS = ("means", "scales", "rotations", "colors", "opacities", "normals", "visibility")


# ----- tool logic ------------------------------------------------------------------------------
def test_combine_modes_and_modifier_keys():
    cur = np.array([1, 1, 0, 0], bool)
    new = np.array([1, 0, 1, 0], bool)
    assert combine(cur, new, "replace").tolist() == [1, 0, 1, 0]
    assert combine(cur, new, "add").tolist() == [1, 1, 1, 0]
    assert combine(cur, new, "subtract").tolist() == [0, 1, 0, 0]
    assert combine(cur, new, "intersect").tolist() == [1, 0, 0, 0]
    out = combine(cur, new, "replace")
    out[:] = False
    assert new.any()  # a new array, never the argument
    with pytest.raises(ValueError, match="combine mode"):
        combine(cur, new, "xor")
    with pytest.raises(ValueError, match="different sizes"):
        combine(cur, new[:3], "add")
    assert combine_mode("replace") == "replace"
    assert combine_mode("intersect", shift=True) == "add"
    assert combine_mode("replace", ctrl=True) == "subtract"
    assert combine_mode("add", shift=True, ctrl=True) == "subtract"  # Ctrl wins
    with pytest.raises(ValueError):
        combine_mode("everything")
    t = ToolSettings()
    assert t.tool == "orbit" and not t.selecting
    t.set_tool("lasso")
    assert t.selecting
    with pytest.raises(ValueError, match="tool"):
        t.set_tool("wand")


def _paste(box, width, height) -> np.ndarray:
    full = np.zeros((height, width), bool)
    h, w = box.mask.shape
    full[box.y0:box.y0 + h, box.x0:box.x0 + w] = box.mask
    return full


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_boxed_regions_equal_the_full_image_regions(seed):
    rng = np.random.default_rng(seed)
    W, H = 90, 70
    a, b = rng.uniform(-10, 100, 2), rng.uniform(-10, 80, 2)
    r = float(rng.uniform(2, 15))
    assert (_paste(brush_box(W, H, a, b, r), W, H) == S.brush_region(W, H, [a, b], r)).all()
    assert (_paste(brush_box(W, H, a, a, r), W, H) == S.brush_region(W, H, [a], r)).all()
    assert (_paste(rect_box(W, H, a, b), W, H) == S.rect_region(W, H, *a, *b)).all()
    poly = rng.uniform(-5, 95, (7, 2))
    assert (_paste(lasso_box(W, H, poly), W, H) == S.lasso_region(W, H, poly)).all()
    assert brush_box(W, H, (-50, -50), (-40, -45), 3).empty  # off screen
    with pytest.raises(ValueError, match="at least 3"):
        lasso_box(W, H, poly[:2])


def _view(through=False):
    """A 20x10 view of 6 snapshot rows naming Gaussians 10..15 of 20 (rows 4, 5 erased-style ids)."""
    snap = SimpleNamespace(ids=np.array([10, 11, 12, 13, 14, 15]))
    cam = SimpleNamespace(width=20, height=10, name="test")
    hits = np.full((10, 20), -1)
    hits[:, 0:5] = 0  # row 0 (Gaussian 10) on the left
    hits[:, 5:10] = 1
    hits[:, 10:15] = 2
    hits[2:4, 15:20] = 3
    pixels = np.array([[2, 5], [7, 5], [12, 5], [17, 3], [17, 8], [-1, -1]])  # row centres (through)
    return StrokeView(cam, snap, through, 20, first_hit=None if through else hits, pixels=pixels if through else None)


def test_brush_stroke_dabs_on_one_id_image_and_combines_with_the_selection():
    before = np.zeros(20, bool)
    before[[3, 12]] = True
    st = Stroke("brush", "add", radius=1.0, before=before, view=_view())
    assert st.move(2.5, 5.5)  # press: a dab on row 0
    assert st.selection().nonzero()[0].tolist() == [3, 10, 12]
    assert not st.move(3.5, 5.5)  # still row 0: nothing new
    assert st.move(7.5, 5.5)  # the segment to x=7.5 crosses row 1
    assert st.touched.nonzero()[0].tolist() == [10, 11]
    assert st.selection().nonzero()[0].tolist() == [3, 10, 11, 12]
    assert st.dabs == 3 and len(st.dab_ms) == 3
    assert (st.before == before).all() and st.before is not before
    sub = Stroke("brush", "subtract", radius=1.0, before=np.ones(20, bool), view=_view())
    sub.move(12.5, 5.5)
    assert sub.selection().sum() == 19 and not sub.selection()[12]
    rep = Stroke("brush", "replace", radius=1.0, before=np.ones(20, bool), view=_view())
    rep.move(17.5, 2.5)
    assert rep.selection().nonzero()[0].tolist() == [13]
    assert rep.label.startswith("brush r=1 1 dabs@test")
    with pytest.raises(ValueError, match="selection tool"):
        Stroke("orbit", "add", 1.0, before)


def test_rectangle_and_lasso_strokes_select_at_their_region():
    st = Stroke("rect", "replace", 1.0, np.zeros(20, bool))
    st.points = [(6.0, 1.0)] * 2
    st.move(11.0, 9.0)
    st.move(16.0, 9.0)  # the moving corner
    assert st.points == [(6.0, 1.0), (16.0, 9.0)]
    st.view = _view()
    assert st.view.gaussians(st.region()).nonzero()[0].tolist() == [11, 12, 13]
    assert st.label == "rect=6,1,16,9@test"
    lasso = Stroke("lasso", "replace", 1.0, np.zeros(20, bool), view=_view())
    for p in [(0.0, 0.0), (1.0, 0.0), (8.0, 0.0), (8.0, 10.0), (0.0, 10.0)]:
        lasso.move(*p)
    assert len(lasso.points) == 4  # (1, 0) was closer than LASSO_MIN_STEP to (0, 0)
    assert lasso.view.gaussians(lasso.region()).nonzero()[0].tolist() == [10, 11]
    small = Stroke("lasso", "replace", 1.0, np.zeros(20, bool), view=_view())
    small.move(1.0, 1.0)
    assert small.region() is None
    # through the body: every row whose centre projects inside, hidden or not; off-screen rows never
    through = _view(through=True)
    assert through.gaussians(rect_box(20, 10, (15, 0), (20, 10))).nonzero()[0].tolist() == [13, 14]
    assert through.gaussians(rect_box(20, 10, (0, 0), (20, 10))).sum() == 5


# ----- the renderer's highlight (EGL) ---------------------------------------------------------------
@pytest.fixture(scope="module")
def gl_renderer():
    from renderer.gl_context import create_offscreen_context
    from renderer.splat_renderer import SplatRenderer

    ctx = create_offscreen_context()
    r = SplatRenderer(ctx)
    yield r
    r.release()
    ctx.release()


def _two_discs(version=1, bad_first=False):
    from reconstruct.snapshot import Snapshot

    means = np.array([(-0.25, 0, 0), (0.25, 0, 0)], np.float32)
    colors = np.array([(0.1, 0.7, 0.3), (0.2, 0.3, 0.9)], np.float32)
    normals = np.array([(0, -1, 0), (1, 0, 0)], np.float32)
    scales, quats = np.full((2, 3), 0.08, np.float32), np.tile(np.float32([1, 0, 0, 0]), (2, 1))
    opac, vis = np.full(2, 1.5, np.float32), np.array([1, 0], np.uint8)
    if bad_first:  # a row the renderer drops: the highlight must still land on the right Gaussian
        means = np.concatenate([np.float32([[np.nan, 0, 0]]), means])
        colors, normals = np.concatenate([colors[:1], colors]), np.concatenate([normals[:1], normals])
        scales, quats = np.concatenate([scales[:1], scales]), np.concatenate([quats[:1], quats])
        opac, vis = np.concatenate([opac[:1], opac]), np.concatenate([vis[:1], vis])
    return Snapshot(means, scales, quats, colors, opac, normals, vis, version=version)


@pytest.mark.gl
@pytest.mark.parametrize("mode", ["rgb", "normal", "depth", "alpha", "visibility"])
def test_highlight_tints_exactly_the_selected_splats_in_every_mode(gl_renderer, mode):
    import dataclasses

    from reconstruct.camera import Camera
    from renderer.render_modes import RenderMode, splat_colors

    r = gl_renderer
    cam = Camera.orbit(0, 0, 3.0, target=(0, 0, 0), width=64, height=64)
    for bad_first in (False, True):
        snap = _two_discs(bad_first=bad_first)
        k = int(bad_first)  # the rows of the two discs
        px = [tuple(np.rint(cam.project(snap.means[i:i + 1].astype(float))[0][0]).astype(int)) for i in (k, k + 1)]
        depth = (2.9, 3.1)
        r.set_snapshot(snap)
        plain = r.render(cam, mode, background=(0, 0, 0), depth_range=depth)
        hl = np.zeros(len(snap), np.uint8)
        hl[k] = 1
        lit = dataclasses.replace(snap, highlight=hl)
        assert not r.set_snapshot(lit)  # only the highlight attribute went up
        assert r.stats.n_highlighted == 1
        tinted = r.render(cam, mode, background=(0, 0, 0), depth_range=depth)
        expect = splat_colors(mode, R=cam.R, t=cam.t, means=snap.means[k:k + 2], colors=snap.colors[k:k + 2],
                              normals=snap.normals[k:k + 2], visibility=snap.visibility[k:k + 2], depth_range=depth,
                              highlight=[1, 0])
        (u0, v0), (u1, v1) = px
        np.testing.assert_allclose(tinted[v0, u0, :3], 0.99 * expect[0], atol=0.015)
        np.testing.assert_allclose(tinted[v1, u1, :3], plain[v1, u1, :3], atol=1e-6)  # unselected: untouched
        assert np.abs(tinted[v0, u0, :3] - plain[v0, u0, :3]).max() > 0.1  # the tint is visible
        hl_rgb = np.asarray(RenderMode.parse(mode).highlight_rgb)
        assert np.abs(tinted[v0, u0, :3] / 0.99 - hl_rgb).max() < np.abs(plain[v0, u0, :3] / 0.99 - hl_rgb).max()
        # no highlight array, or nothing selected: the plain image
        r.set_snapshot(dataclasses.replace(snap, highlight=np.zeros(len(snap), np.uint8)))
        assert r.stats.n_highlighted == 0
        np.testing.assert_array_equal(r.render(cam, mode, background=(0, 0, 0), depth_range=depth), plain)
        r.set_snapshot(snap)
        np.testing.assert_array_equal(r.render(cam, mode, background=(0, 0, 0), depth_range=depth), plain)
    with pytest.raises(ValueError, match="highlight"):
        r.set_snapshot(dataclasses.replace(_two_discs(version=7), highlight=np.ones(5, np.uint8)))


# ----- the trainer thread's edit queue -------------------------------------------------------------
@pytest.fixture
def thread(tiny_scene, tiny_config, tmp_path):
    from app.studio.trainer_thread import TrainerThread
    from reconstruct.train.trainer import Trainer

    run = tmp_path / "run"
    run.mkdir()
    t = Trainer(tiny_scene, tiny_config, run)
    for _ in range(3):
        t.step()
    return TrainerThread(t)  # not started: its queue runs calls at once, as between two steps


def test_edits_go_through_the_trainer_queue_and_undo_bit_exactly(thread, tmp_path):
    from reconstruct.edits import Erase, Recolour
    from reconstruct.edits.store import load_edits

    session = thread.edit_session
    assert session is not None and session.run_dir == tmp_path / "run"
    thread._publish(thread.controls.get())
    before = thread.latest_snapshot()
    sel = session.select_part("head").copy()
    assert 0 < sel.sum() < len(sel)
    # the highlight: the same Gaussians at every pose and in both spaces (one flag per row)
    other = thread.trainer.state.snapshot("canonical", 2)
    assert (session.highlight(other) == sel).all() and (session.highlight(before) == sel).all()
    entry = thread.edit(lambda s: s.apply(Erase(), mask=sel.copy(), label="part=head")).result(timeout=60)
    after = thread.latest_snapshot()
    assert after.version > before.version and entry.count == sel.sum()
    assert after.ids is not None and (after.ids == np.flatnonzero(~sel)).all()
    for k in ARRAYS:
        np.testing.assert_array_equal(getattr(after, k), getattr(before, k)[~sel])
    doc = json.loads((tmp_path / "run" / "edits" / "edits.json").read_text())
    assert [(d["id"], d["op"], d["count"], d["label"]) for d in doc["applied"]] == [(1, "erase", sel.sum(), "part=head")]
    # the highlight of a snapshot with erased rows left out: mapped through its ids
    session.select_part("head,neck")
    neck = S.part_mask(thread.trainer.state.model.parts(), "neck")
    assert (session.highlight(after) == neck[after.ids]).all()
    thread.edit(lambda s: s.apply(Recolour(90, 1.0, 1.0), mask=neck, label="neck")).result(timeout=60)
    assert thread.edit(lambda s: s.undo()).result(timeout=60).op.name == "recolour"
    assert thread.edit(lambda s: s.undo()).result(timeout=60).op.name == "erase"
    back = thread.latest_snapshot()
    assert back.ids is None
    for k in ARRAYS:
        np.testing.assert_array_equal(getattr(back, k), getattr(before, k))  # bit-exact
    assert thread.edit(lambda s: s.redo()).result(timeout=60).op.name == "erase"
    again = thread.latest_snapshot()
    for k in ARRAYS:
        np.testing.assert_array_equal(getattr(again, k), getattr(after, k))
    stored = load_edits(tmp_path / "run", session.num_gaussians)
    assert [e.op.name for e in stored.applied] == ["erase"] and [e.op.name for e in stored.undone] == ["recolour"]
    # an error comes back through the Future; nothing changes
    fut = thread.edit(lambda s: s.apply(Erase(), mask=np.zeros(s.num_gaussians, bool)))
    with pytest.raises(ValueError, match="nothing is selected"):
        fut.result(timeout=60)
    assert len(session.entries()) == 1
    # a new thread on the same run folder (the studio reopened) loads the edits, redo stack included
    from app.studio.trainer_thread import TrainerThread

    reopened = TrainerThread(thread.trainer)
    assert [e.id for e in reopened.edit_session.entries()] == [1]
    assert [e.id for e in reopened.edit_session.undone] == [2]


def test_guidance_steps_need_stage2_and_the_session_follows_its_plan(thread):
    from reconstruct.stage2.config import Stage2Config

    with pytest.raises(ValueError, match="Stage II"):
        thread.guidance_steps(2).result(timeout=60)
    assert thread.edit_session.plan is None
    thread.controls.update(stage2=Stage2Config(iters=40, num_azimuths=12, prior_size=48).to_dict(),
                           start_stage2=True)
    thread._start_stage2(thread.controls.get())
    t = thread.trainer
    assert t.stage == 2, thread.stage2_message
    assert thread.edit_session.plan is t.plan  # edits made from now on refresh Stage II's views and colours
    kinds, steps = dict(t.kind_counts), t.stage_step
    assert thread.guidance_steps(3).result(timeout=120) == 3
    assert t.stage_step == steps + 3
    new = {k: v - kinds.get(k, 0) for k, v in t.kind_counts.items() if v != kinds.get(k, 0)}
    assert sum(new.values()) == 3 and set(new) <= {"canonical", "observation"}, new
    assert "next_kind" not in vars(t.plan)  # the plan's own mix again


# ----- the window, driven by real input (Xvfb + xdotool: tests/studio_window.py) ---------------------------
SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"
RECT = ((560, 300), (720, 520))  # over the avatar's belly and thighs in the 1280 x 800 window


@pytest.mark.gl
def test_rectangle_erase_undo_redo_in_the_window(tmp_path):
    with studio_in_xvfb(tmp_path, SCENE, wait_timeout=60.0, move_pause=0.15) as win:
        run = win.run
        win.wait("training", lambda s: s["step"] >= 2 and s["snapshot"]["n"] > 0, timeout=180)
        win.attach()
        win.click("pause")  # a fixed avatar: the snapshots below differ by the edits alone
        st = win.wait("paused", lambda s: s["controls"]["paused"] and s["snapshot"]["step"] == s["step"]
                      and s["drawn"] and s["drawn"][0] == s["snapshot"]["version"])
        n = st["snapshot"]["n"]
        assert st["edits"]["selected"] == 0 and st["edits"]["applied"] == []

        # the rectangle tool from the tool bar opens the Edit panel; a drag selects instead of orbiting
        plain = win.screenshot("plain")
        win.click("tool_rect")
        win.wait("rectangle tool", lambda s: s["edits"]["tool"] == "rect" and s["edits"]["panel"])
        win.drag(*RECT)
        st = win.wait("a selection", lambda s: s["edits"]["selected"] > 0 and s["drawn"][0] == s["snapshot"]["version"])
        selected = st["edits"]["selected"]
        assert selected < n
        time.sleep(0.3)
        lit = win.screenshot("lit")
        before = win.arrays("before")
        assert before["selection"].sum() == selected and before["ids"].tolist() == [-1]

        # Erase: applied between steps; the next snapshot lost exactly the selected rows
        win.click("op_erase")
        st = win.wait("erase", lambda s: not s["edits"]["pending"] and len(s["edits"]["applied"]) == 1)
        assert st["edits"]["applied"] == [[1, "erase", selected]] and st["edits"]["message"] is None
        st = win.wait("erased snapshot", lambda s: s["snapshot"]["n"] == n - selected)
        erased = win.arrays("erased")
        keep = ~before["selection"]
        assert (erased["ids"] == np.flatnonzero(keep)).all()
        for k in ARRAYS:
            np.testing.assert_array_equal(erased[k], before[k][keep])
        doc = json.loads((run / "edits" / "edits.json").read_text())
        assert [(d["id"], d["op"], d["count"]) for d in doc["applied"]] == [(1, "erase", selected)]

        # Ctrl+Z (the mouse over the view: the keys go to the window, imgui does not want them)
        win.move(640, 700)
        win.key("ctrl+z")
        st = win.wait("undo", lambda s: not s["edits"]["pending"] and s["edits"]["applied"] == []
                      and s["snapshot"]["n"] == n)
        assert st["edits"]["undone"] == [[1, "erase", selected]]
        undone = win.arrays("undone")
        assert undone["ids"].tolist() == [-1]
        for k in ARRAYS:
            np.testing.assert_array_equal(undone[k], before[k])  # bit-exact
        assert json.loads((run / "edits" / "edits.json").read_text())["applied"] == []

        # Ctrl+Shift+Z redoes it
        win.key("ctrl+shift+z")
        win.wait("redo", lambda s: not s["edits"]["pending"] and len(s["edits"]["applied"]) == 1
                 and s["snapshot"]["n"] == n - selected)
        redone = win.arrays("redone")
        for k in ARRAYS + ("ids",):
            np.testing.assert_array_equal(redone[k], erased[k])
        win.quit()
    assert win.app.returncode == 0, win.log
    # the highlight: inside the rectangle the avatar turned orange; elsewhere in the view nothing changed
    (xa, ya), (xb, yb) = RECT
    inside = (slice(ya + 4, yb - 4), slice(xa + 4, xb - 4))
    warmer = (lit[..., 0] - lit[..., 2]) - (plain[..., 0] - plain[..., 2])
    assert (warmer[inside] > 40).mean() > 0.5, (warmer[inside] > 40).mean()
    view = np.zeros(lit.shape[:2], bool)
    view[60:790, 400:940] = True  # between the panels, under the tool bar
    view[ya - 80:yb + 80, xa - 80:xb + 80] = False  # the selected splats' footprints reach past the rectangle
    assert (np.abs(lit - plain).max(-1)[view] > 6).mean() < 0.002


def test_controller_strokes_highlight_and_requests(thread):
    """The window's editor without a window: strokes on the drawn view, the highlight of the drawn
    snapshot, and apply / undo / redo through the trainer thread (polled as the GL thread does)."""
    from app.studio.edit_controller import EditController
    from reconstruct.edits import Erase

    snap = thread.trainer.state.snapshot("observation", 0)
    cam = thread.trainer.scene.frames[0].camera
    app = SimpleNamespace(trainer=thread, view=SimpleNamespace(edit_panel=False), drawn_view=(cam, snap))
    ed = EditController(app)
    session = ed.session
    assert not ed.begin_stroke(10, 10)  # the orbit tool does not select
    ed.set_tool("brush")
    assert app.view.edit_panel  # picking a selection tool opens the Edit panel
    ed.tools.radius = 6.0
    assert ed.begin_stroke(0.5 * cam.width, 0.3 * cam.height)
    first = ed.selected_count
    assert first > 0 and ed.timings[-1].first_hit_ms > 0
    ed.move_stroke(0.5 * cam.width, 0.6 * cam.height)
    assert ed.selected_count > first  # the highlight follows the brush
    lit = ed.highlighted(snap, snap)
    assert lit.highlight.sum() == ed.selected_count and lit.means is snap.means
    assert ed.highlighted(snap, snap) is lit  # cached until the selection or the snapshot changes
    ed.finish_stroke()
    assert session.selection_label.startswith("brush r=6 ")
    # Ctrl held at the press: a rectangle subtracts from the brush's selection
    ed.set_tool("rect")
    before = session.selection.copy()
    ed.begin_stroke(0, 0, ctrl=True)
    ed.move_stroke(cam.width, 0.45 * cam.height)
    assert (session.selection == before).all()  # a rectangle selects at its release
    ed.finish_stroke(cam.width, 0.45 * cam.height)
    assert 0 < session.selection.sum() < before.sum() and not (session.selection & ~before).any()
    # through the body: the same Gaussians as the library's screen_mask
    view = StrokeView.make(cam, snap, session.num_gaussians, through=True)
    full = rect_box(cam.width, cam.height, (0, 0), (cam.width, cam.height))
    expect = S.screen_mask(snap, cam, np.ones((cam.height, cam.width), bool), session.num_gaussians, through=True)
    assert (view.gaussians(full) == expect).all()
    # requests: the thread is not running, so they run at once; poll takes the result
    sel = session.selection.copy()
    assert ed.apply(Erase())
    ed.poll()
    assert not ed.busy and ed.panel.result.startswith("applied #1 erase") and ed.panel.message is None
    assert thread.latest_snapshot().ids is not None and len(thread.latest_snapshot()) == len(snap) - sel.sum()
    ed.clear()
    assert not ed.apply(Erase()) and "nothing is selected" in ed.panel.message
    assert ed.undo()
    ed.poll()
    assert ed.panel.result.startswith("undo: #1 erase")
    assert [(e.id, applied) for e, applied in ed.entries()] == [(1, False)]
    assert not ed.undo()  # nothing left to undo
    assert ed.redo()
    ed.poll()
    assert [(e.id, applied) for e, applied in ed.entries()] == [(1, True)]
