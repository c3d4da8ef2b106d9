"""Headless ``train`` and ``eval`` commands."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from tqdm import tqdm


class RunLockedError(RuntimeError):
    pass


class RunLock:
    """Refuses a second training process on the same run folder (a pid file, stale ones ignored)."""

    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / ".lock"

    def __enter__(self):
        if self.path.exists():
            try:
                pid = int(self.path.read_text().strip() or 0)
                os.kill(pid, 0)
                raise RunLockedError(f"{self.path.parent}: another training process (pid {pid}) is using this run folder")
            except (ValueError, ProcessLookupError, PermissionError):
                pass  # stale lock
        self.path.write_text(str(os.getpid()))
        return self

    def __exit__(self, *exc):
        self.path.unlink(missing_ok=True)


def train(scene_spec: str, run_dir: Path, config, *, progress: bool = True):
    """Train until the run's steps or minutes are used up; returns the session."""
    from app.run_setup import open_session
    from reconstruct.train.report import error_vs_time_table, plot_error_vs_time

    run_dir.mkdir(parents=True, exist_ok=True)
    with RunLock(run_dir):
        session = open_session(scene_spec, run_dir, config, progress=progress)
        config = session.config
        if session.lpips_note:
            print(session.lpips_note, file=sys.stderr)
        if not session.use_normals:
            print("normal loss left out: the scene has no normal maps", file=sys.stderr)
        width, height = session.scene.image_size
        print(f"{session.model.num_gaussians} Gaussians, images {width}x{height}, "
              f"target {config.iters} steps" + (f" or {config.minutes:g} min" if config.minutes else ""), file=sys.stderr)
        session.maybe_evaluate(force=session.step_count == 0)
        bar = tqdm(total=config.iters, initial=session.step_count, desc="stage I", disable=not progress, unit="it")
        try:
            while not session.done:
                out, _ = session.advance()
                bar.update()
                if session.step_count % 25 == 0 and not out.get("skipped"):
                    bar.set_postfix(loss=f"{out['loss']:.4f}", psnr=f"{out['psnr_train']:.1f}",
                                    seen=f"{session.latest.get('seen_psnr', float('nan')):.1f}",
                                    unseen=f"{session.latest.get('unseen_psnr', float('nan')):.1f}")
        finally:
            bar.close()
            session.save()
        session.maybe_evaluate(force=True)
        session.save()
        records = session.log.read("eval")
        print(error_vs_time_table(records))
        print(f"wrote {plot_error_vs_time(run_dir)}", file=sys.stderr)
    return session


def evaluate(run_dir: Path, *, as_json: bool) -> int:
    from app.run_setup import check_run, resume_run
    from reconstruct.train.report import plot_error_vs_time

    info = check_run(run_dir, "evaluate")
    session = resume_run(run_dir, info)
    rows, summary = session.evaluate()
    result = {"run": str(run_dir), "scene": info["scene"], "step": session.step_count, **summary, "views": rows}
    if session.lpips_note:
        result["note"] = session.lpips_note
    if as_json:
        print(json.dumps(result, indent=1))
    else:
        for r in rows:
            print(f"{r['view']:<14} frame {r['frame']:>3} {'seen' if r['seen'] else 'unseen':<7} "
                  f"PSNR {r['psnr']:6.2f}  SSIM {r['ssim']:.4f}")
        print(" ".join(f"{k}={v:.4f}" for k, v in summary.items() if v is not None))
    try:
        print(f"wrote {plot_error_vs_time(run_dir)}", file=sys.stderr)
    except ValueError as exc:
        print(f"no error-vs-time plot: {exc}", file=sys.stderr)
    return 0
