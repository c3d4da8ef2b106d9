"""Studio: training iterations/s with and without the window, and the window's frame rate.

Stage I on the default demo scene (synthetic:seed=0, default Stage1Config, torch threads as the app
leaves them; periodic evaluation off so that it does not land in one measurement and not another).
Each measurement is its own process; the kinds are interleaved (A B C A B C ...) because other
work shares this machine's cores, and the load average is printed with every row:

* headless -- the trainer thread alone (``TrainerThread``, as in the studio);
* window idle -- ``run_studio`` under Xvfb, nobody touching it (the loop drops to ``idle_fps``);
* window active -- the same with continuous interaction simulated (the loop runs at ``max_fps``,
  as while the user drags the camera or a slider).

    python benchmarks/studio.py [--seconds 40] [--warmup 12] [--rounds 2] [--json out.json]
    xvfb-run -a -s "-screen 0 1600x1000x24" python benchmarks/studio.py --screenshots docs   # docs/ images
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("headless", "window idle", "window active")


def _config():
    from reconstruct.train.config import Stage1Config

    return Stage1Config(eval_every_seconds=1e9, checkpoint_every_seconds=1e9)


def child(kind: str, seconds: float, warmup: float, out: str) -> None:
    sys.path.insert(0, str(ROOT))
    import reconstruct  # noqa: F401 -- OMP_WAIT_POLICY before torch
    from reconstruct.data.load import DEFAULT_SCENE

    result: dict = {"kind": kind}
    if kind == "headless":
        from app.studio.trainer_thread import TrainerThread
        from reconstruct.data.load import load_scene
        from reconstruct.train.trainer import Trainer

        trainer = TrainerThread(Trainer(load_scene(DEFAULT_SCENE, progress=False), _config())).start()
        time.sleep(warmup)
        s0, t0 = trainer.status().step, time.perf_counter()
        time.sleep(seconds)
        s1, t1 = trainer.status().step, time.perf_counter()
        trainer.stop(save=False)
        result.update(its=(s1 - s0) / (t1 - t0), fps=None, steps=s1 - s0)
    else:
        from app.studio.window import run_studio

        active = kind == "window active"
        mark: dict = {}

        def script(app):
            now = time.perf_counter()
            if active:
                app.pacer.note_input()  # as if the user kept interacting
            mark.setdefault("start", now)
            if "t0" not in mark and now - mark["start"] >= warmup:
                mark.update(t0=now, s0=app.status.step, f0=app.frame_count)
            elif "t0" in mark and now - mark["t0"] >= seconds:
                mark.update(t1=now, s1=app.status.step, f1=app.frame_count)
                app.close()

        run_studio(DEFAULT_SCENE, None, config=_config(), size=(1280, 800), script=script, progress=False)
        dt = mark["t1"] - mark["t0"]
        result.update(its=(mark["s1"] - mark["s0"]) / dt, fps=(mark["f1"] - mark["f0"]) / dt, steps=mark["s1"] - mark["s0"])
    result["load"] = os.getloadavg()
    Path(out).write_text(json.dumps(result))


def screenshots(folder: str, train_s: float, run: str | None = None) -> None:
    """docs/ screenshots of the window on the demo scene: training panel with plots after
    ``train_s`` seconds, then Stage II started (its panel with the λ_SDS curve), then the
    visibility map beside the ground truth."""
    sys.path.insert(0, str(ROOT))
    import reconstruct  # noqa: F401
    from app.studio.window import run_studio
    from reconstruct.data.load import DEFAULT_SCENE
    from reconstruct.train.config import Stage1Config

    out = Path(folder)
    st: dict = {"phase": 0}

    def script(app):
        now = time.perf_counter()
        st.setdefault("t", now)
        p, s = st["phase"], app.status
        if p == 0 and now - st["t"] > train_s:
            app.request_screenshot(out / "studio_main_window.png")
            app.push_stage2_settings(canonical_ratio=0.6)
            app.start_stage2()
            st["phase"] = 1
        elif p == 1 and s.stage == 2 and s.stage_step >= 4:
            app.request_screenshot(out / "studio_stage2.png")
            st["phase"] = 4
        elif p == 4:  # a frame later: the visibility map from an unseen evaluation view, beside its ground truth
            app.set_mode("visibility")
            app.view.show_ground_truth = True
            app.view.show_gui = False  # the panels would cover the two halves
            unseen = [k for k, v in enumerate(app.scene.eval_views) if not v.seen and abs(v.azimuth_deg) >= 60]
            app.snap_to_eval_view(unseen[0] if unseen else 0)
            st["phase"], st["t2"] = 2, now
        elif p == 1 and s.stage2_message:
            print("Stage II:", s.stage2_message)
            st["phase"], st["t2"] = 2, now
            app.set_mode("visibility")
            app.view.show_ground_truth = True
        elif p == 2 and now - st["t2"] > 3:
            app.request_screenshot(out / "studio_visibility_map.png")
            st["phase"] = 3
        elif p == 3:
            app.close()

    if run is None:
        run_studio(DEFAULT_SCENE, None, config=Stage1Config(eval_every_seconds=20), size=(1280, 800), script=script,
                   progress=False)
        return
    import json
    import shutil
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:  # a copy: closing the window saves into the run
        copy = Path(tmp) / "run"
        shutil.copytree(run, copy, ignore=shutil.ignore_patterns(".lock"))
        scene = json.loads((copy / "run.json").read_text())["scene"]
        run_studio(scene, copy, size=(1280, 800), script=script, progress=False)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--warmup", type=float, default=12.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--json", default=None)
    ap.add_argument("--screenshots", metavar="DIR", default=None, help="write the docs/ screenshots instead")
    ap.add_argument("--train-seconds", type=float, default=90.0, help="with --screenshots: training before the first")
    ap.add_argument("--run", default=None, help="with --screenshots: open (a copy of) this trained Stage I run")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.seconds, args.warmup, args.out)
        return 0
    if args.screenshots:
        screenshots(args.screenshots, args.train_seconds, args.run)
        return 0
    kinds = [k.strip() for k in args.kinds.split(",")]
    rows = []
    tmp = Path(os.environ.get("TMPDIR", "/tmp")) / f"studio_bench_{os.getpid()}.json"
    print(f"{'round':>5}  {'kind':<14} {'it/s':>6} {'GUI fps':>8}  load before -> after (1 min)")
    for r in range(args.rounds):
        for kind in kinds:
            before = os.getloadavg()[0]
            cmd = [sys.executable, __file__, "--child", kind, "--seconds", str(args.seconds), "--warmup",
                   str(args.warmup), "--out", str(tmp)]
            if kind != "headless":
                cmd = ["xvfb-run", "-a", "-s", "-screen 0 1600x1000x24"] + cmd
            subprocess.run(cmd, check=True, cwd=str(ROOT), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            res = json.loads(tmp.read_text())
            res.update(round=r, load_before=before)
            rows.append(res)
            fps = f"{res['fps']:8.1f}" if res["fps"] is not None else f"{'-':>8}"
            print(f"{r:>5}  {kind:<14} {res['its']:6.2f} {fps}  {before:.2f} -> {res['load'][0]:.2f}", flush=True)
    tmp.unlink(missing_ok=True)
    print()
    base = [x["its"] for x in rows if x["kind"] == "headless"]
    for kind in kinds:
        its = [x["its"] for x in rows if x["kind"] == kind]
        fps = [x["fps"] for x in rows if x["kind"] == kind and x["fps"] is not None]
        line = f"{kind:<14} mean {sum(its) / len(its):5.2f} it/s"
        if fps:
            line += f", {sum(fps) / len(fps):5.1f} fps"
        if base and kind != "headless":
            line += f", {100 * (1 - (sum(its) / len(its)) / (sum(base) / len(base))):+5.1f}% slower than headless"
        print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
