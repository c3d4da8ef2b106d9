"""Stroke-to-frame latency of the studio's brush (docs/editing.md, "In the studio window").

Opens the studio window (run it under Xvfb) on a copy of a run folder -- or, without ``--run``, a
tiny synthetic run trained for a few steps -- pauses training, and draws ``--strokes`` brush
strokes of ``--dabs`` mouse moves each across the avatar through ``EditController`` (what the
mouse handler calls), one move per frame, as a drag does. Prints, in ms, median and p90:

* first-hit render -- the visible-surface id image of the drawn snapshot, once per stroke;
* dab selection -- one brush dab on that image (the dab's box only) and the combine;
* highlight gather -- the selection's flags for the drawn snapshot's rows;
* splat render -- the window's splat render of a stroke's frame (1280 x 800, the highlight
  attribute uploaded, no sort: the camera does not move), with a ``finish`` to count the draw;
* dab -> highlighted frame -- from the mouse move being handled to ``swap_buffers`` returning on
  the frame that shows the new highlight (the dab, the gather, the highlight upload, the splat
  render, the panels, the swap);
* press -> first highlighted frame -- the same for the press, which includes the first-hit render.

A real mouse adds the wait for the next frame (at most 1/30 s while the user interacts).

    xvfb-run -a -s "-screen 0 1600x1000x24" python benchmarks/edit_latency.py [--run RUN] [--strokes 20]
        [--dabs 12] [--radius 16] [--screenshots docs]

``--screenshots DIR`` also writes the docs' pictures of each tool and of the edit list
(``editing_window_*.png``). The run folder given is copied first and never changed.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TINY_SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"
SIZE = (1280, 800)


def _tiny_config():
    from reconstruct.avatar.config import AvatarConfig
    from reconstruct.train.config import Stage1Config

    return Stage1Config(iters=100000, eval_every_seconds=1e9, checkpoint_every_seconds=1e9, crop_margin=4,
                        avatar=AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8,
                                            pose_feature_channels=8, hidden=32))


def stats(values) -> tuple[float, float, int]:
    v = np.asarray(list(values), np.float64)
    if v.size == 0:
        return float("nan"), float("nan"), 0
    return float(np.median(v)), float(np.percentile(v, 90)), int(v.size)


def part_box(app, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The centre and half-size on screen of a body part of the drawn avatar."""
    from reconstruct.edits.selection import part_mask

    cam, snap = app.drawn_view
    mask = part_mask(app.trainer.trainer.state.model.parts(), name)
    rows = mask if snap.ids is None else mask[np.asarray(snap.ids)]
    uv, _ = cam.project(np.asarray(snap.means, np.float64)[rows])
    lo, hi = np.percentile(uv, 5, axis=0), np.percentile(uv, 95, axis=0)
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def avatar_box(app) -> tuple[np.ndarray, np.ndarray]:
    """The 10th-90th percentile box of the drawn avatar's visible rows on screen (x, y)."""
    cam, snap = app.drawn_view
    uv, z = cam.project(np.asarray(snap.means, np.float64))
    ok = (z > cam.near) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return np.percentile(uv[ok], 10, axis=0), np.percentile(uv[ok], 90, axis=0)


class Bench:
    """The script run once per frame: a small state machine over frames."""

    def __init__(self, args) -> None:
        self.args = args
        self.rng = np.random.default_rng(0)
        self.phase = "wait"
        self.todo: list = []  # callables, one per frame, for the current phase
        self.done_at: int | None = None
        self.result: dict = {}
        self.render_ms: list[float] = []  # the splat renders of the strokes' frames (draw + finish)

    def time_renders(self, app) -> None:
        """Time each splat render of the window (with a finish, so the draw is counted)."""
        render = app.renderer.render

        def timed(*a, **k):
            t0 = time.perf_counter()
            out = render(*a, **k)
            app.ctx.finish()
            if self.phase == "strokes":
                self.render_ms.append((time.perf_counter() - t0) * 1e3)
            return out
        app.renderer.render = timed

    def __call__(self, app) -> None:
        if self.phase == "wait":
            if app.drawn_view is not None and len(app.drawn_view[1]) and app.frame_count > 5:
                app.pause(True)
                self.phase = "settle"
                self.wait_until = app.frame_count + 5
            return
        if self.phase == "settle":
            if app.frame_count >= self.wait_until and app.status.paused:
                self.time_renders(app)
                self.phase = "strokes"
                self.todo = self.stroke_plan(app)
            return
        if self.todo:
            step = self.todo.pop(0)
            step(app)
            return
        if self.phase == "strokes":
            self.result["timings"] = list(app.edits.timings)
            self.result["gaussians"] = app.edits.session.num_gaussians
            self.result["rows"] = len(app.drawn_view[1])
            app.edits.clear()
            if self.args.screenshots:
                self.phase = "shots"
                self.todo = self.shot_plan(app, Path(self.args.screenshots))
                return
            self.phase = "end"
            return
        if self.phase in ("shots", "end") and not app.edits.busy:
            app.close()

    # ----- the latency strokes ------------------------------------------------------------------
    def stroke_plan(self, app) -> list:
        ed = app.edits
        lo, hi = avatar_box(app)
        plan = [lambda a: (ed.set_tool("brush"), setattr(ed.tools, "radius", self.args.radius))]
        for _ in range(self.args.strokes):
            p0, p1 = self.rng.uniform(lo, hi), self.rng.uniform(lo, hi)
            plan.append(lambda a, p=p0: (ed.clear(), ed.begin_stroke(*p)))
            for k in range(1, self.args.dabs + 1):
                plan.append(lambda a, p=p0 + (p1 - p0) * k / self.args.dabs: ed.move_stroke(*p))
            plan.append(lambda a: ed.finish_stroke())
            plan.append(lambda a: None)  # the release's frame
        return plan

    # ----- the docs' screenshots ------------------------------------------------------------------
    def shot_plan(self, app, out: Path) -> list:
        from reconstruct.edits import Erase, Lock, PaintUnseen, Recolour

        ed = app.edits
        lo, hi = avatar_box(app)
        at = lambda fx, fy: lo + (hi - lo) * np.array([fx, fy])  # noqa: E731 -- a point of the avatar's box
        shot = lambda name: (lambda a: a.request_screenshot(out / f"editing_window_{name}.png"))  # noqa: E731
        wait = [lambda a: a.export.saved_screenshots.clear()] * 3  # (the Export panel names the last one)
        plan: list = [lambda a: (a.set_mode("rgb"), ed.clear(), ed.set_tool("brush"),
                                 setattr(ed.tools, "radius", 18.0))]
        # brush: a stroke across the chest, the shot mid-stroke (the cursor at the brush)
        path = [at(0.30, 0.28), at(0.45, 0.33), at(0.6, 0.3), at(0.7, 0.38)]
        plan.append(lambda a: ed.begin_stroke(*path[0]))
        for k in range(1, 16):
            t = k / 15 * (len(path) - 1)
            i = min(int(t), len(path) - 2)
            p = path[i] + (path[i + 1] - path[i]) * (t - i)
            plan.append(lambda a, p=p: ed.move_stroke(*p))
        plan += wait + [shot("brush")] + wait + [lambda a: ed.finish_stroke()]
        # rectangle: one released over the left leg, a second one (Shift: add) being dragged
        plan.append(lambda a: (ed.clear(), ed.set_tool("rect")))
        plan.append(lambda a: ed.begin_stroke(*at(0.2, 0.62)))
        plan.append(lambda a: ed.move_stroke(*at(0.48, 0.95)))
        plan.append(lambda a: ed.finish_stroke(*at(0.48, 0.95)))
        plan.append(lambda a: ed.begin_stroke(*at(0.55, 0.62), shift=True))
        plan.append(lambda a: ed.move_stroke(*at(0.85, 0.8)))
        plan += wait + [shot("rect")] + wait + [lambda a: ed.finish_stroke(*at(0.85, 0.8))]
        # lasso, in the visibility mode: around the head, a second loop being drawn round the belly
        plan.append(lambda a: (ed.clear(), ed.set_tool("lasso"), a.set_mode("visibility")))

        head, half = part_box(app, "head")

        def loop(cx, cy, rx, ry, n=24, shift=False, close=True):
            pts = [np.array([cx + rx * np.cos(2 * np.pi * k / n), cy + ry * np.sin(2 * np.pi * k / n)])
                   for k in range(n)]
            steps = [lambda a, p=pts[0]: ed.begin_stroke(*p, shift=shift)]
            steps += [lambda a, p=p: ed.move_stroke(*p) for p in pts[1:]]
            if close:
                steps.append(lambda a, p=pts[-1]: ed.finish_stroke(*p))
            return steps

        plan += loop(head[0], head[1] + 0.3 * half[1], 1.2 * half[0], 0.8 * half[1])  # the face
        belly = at(0.5, 0.42)
        plan += loop(belly[0], belly[1], 0.25 * (hi - lo)[0], 0.08 * (hi - lo)[1], n=18, shift=True, close=False)[:-4]
        plan += wait + [shot("lasso")] + wait + [lambda a: ed.finish_stroke()]
        # part selection (arms, grown by one texel), in the canonical space and the normals mode
        plan.append(lambda a: (ed.set_tool("orbit"), a.set_mode("normal"), a.set_space("canonical"),
                               setattr(ed.panel, "part", "arms"), ed.select_part(), ed.grow(1)))
        plan.append(_until_space("canonical"))
        plan += wait + [shot("part")] + wait
        plan.append(lambda a: a.set_space("observation"))
        plan.append(_until_space("observation"))
        plan.append(lambda a: a.snap_to_training_camera())
        # several edits, one undone: the edit list (RGB)
        ops = [lambda a: (a.set_mode("rgb"), ed.select_part("arms"), ed.apply(Recolour(150.0, 1.2, 1.0))),
               lambda a: (ed.select_part("head"), ed.apply(Lock())),
               lambda a: (ed.select_part("legs"), ed.apply(Recolour(-60.0, 0.6, 0.8))),
               lambda a: (ed.set_tool("rect"), ed.begin_stroke(*at(0.35, 0.3)), ed.move_stroke(*at(0.65, 0.5)),
                          ed.finish_stroke(*at(0.65, 0.5)), ed.apply(PaintUnseen())),
               lambda a: ed.apply(Erase()),
               lambda a: ed.undo()]
        for op in ops:
            plan.append(op)
            plan += [lambda a: None] * 2
            plan.append(_until_idle)
        plan.append(lambda a: (ed.set_tool("orbit"), ed.clear()))
        plan += wait + [shot("edits")] + wait
        return plan


def _until_space(space: str):
    def wait(app) -> None:
        """Hold the plan until the snapshot of ``space`` is drawn."""
        if app.drawn_view is None or app.drawn_view[1].space != space or app.last_drawn_snapshot[0] != \
                app.latest_snapshot().version:
            raise _NotYet(wait)
    return wait


def _until_idle(app) -> None:
    """Hold the plan until the edit request in flight is done (re-queued by the caller)."""
    if app.edits.busy:
        raise _NotYet(_until_idle)


class _NotYet(Exception):
    """A plan step that has to wait: ``step`` is run again on the next frame."""

    def __init__(self, step) -> None:
        super().__init__("not yet")
        self.step = step


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", type=Path, default=None, help="a run folder (copied first); default: a tiny synthetic run")
    ap.add_argument("--strokes", type=int, default=20)
    ap.add_argument("--dabs", type=int, default=12, help="mouse moves (dabs) per stroke")
    ap.add_argument("--radius", type=float, default=16.0, help="brush radius (px)")
    ap.add_argument("--screenshots", default=None, help="also write the docs' editing_window_*.png here")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    from app.studio.window import run_studio

    with tempfile.TemporaryDirectory(prefix="edit_latency_") as tmp:
        run = Path(tmp) / "run"
        if args.run is not None:
            shutil.copytree(args.run, run, ignore=shutil.ignore_patterns(".lock", "edits"))
            scene, config = json.loads((run / "run.json").read_text())["scene"], None
        else:
            scene, config = TINY_SCENE, _tiny_config()
        bench = Bench(args)

        def script(app):
            try:
                bench(app)
            except _NotYet as exc:
                bench.todo.insert(0, exc.step)

        t0 = time.perf_counter()
        rc = run_studio(scene, run, config=config, size=SIZE, script=script, progress=False, max_fps=60.0,
                        max_frames=20000)
        wall = time.perf_counter() - t0
    if rc != 0 or "timings" not in bench.result:
        print(f"the studio ended early (rc {rc})", file=sys.stderr)
        return 1
    timings = bench.result["timings"]
    rows = {
        "first-hit render (per stroke)": [t.first_hit_ms for t in timings],
        "dab selection (per dab)": [d for t in timings for d in t.dab_ms],
        "highlight gather (per dab)": [h for t in timings for h in t.highlight_ms],
        "splat render of a stroke's frame (draw + finish)": bench.render_ms,
        "dab -> highlighted frame": [f for t in timings for f in t.to_frame_ms[1:]],
        "press -> first highlighted frame": [t.to_frame_ms[0] for t in timings if t.to_frame_ms],
    }
    print(f"{bench.result['gaussians']} Gaussians ({bench.result['rows']} drawn), window {SIZE[0]} x {SIZE[1]}, "
          f"{len(timings)} strokes x {args.dabs} dabs, brush radius {args.radius:g} px ({wall:.0f} s in all)")
    print("| ms | median | p90 | n |\n|---|---|---|---|")
    out = {}
    for name, values in rows.items():
        med, p90, n = stats(values)
        out[name] = {"median": med, "p90": p90, "n": n}
        print(f"| {name} | {med:.1f} | {p90:.1f} | {n} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"gaussians": bench.result["gaussians"], "rows": out}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
