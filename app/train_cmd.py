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
    """Refuses a second training process on the same run folder: an exclusive ``flock`` on
    ``RUN/.lock`` held for the whole run (the kernel drops it when the process dies, even by
    SIGKILL), with the holder's pid written inside for the message."""

    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / ".lock"
        self._fh = None

    def __enter__(self):
        import fcntl

        fh = open(self.path, "a+")
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.seek(0)
            pid = fh.read().strip() or "?"
            fh.close()
            raise RunLockedError(f"{self.path.parent}: another training process (pid {pid}) is using this run folder")
        fh.seek(0)
        fh.truncate()
        fh.write(str(os.getpid()))
        fh.flush()
        self._fh = fh
        return self

    def __exit__(self, *exc):
        import fcntl

        if self._fh is not None:  # the file stays (unlinking it would let two holders lock two inodes)
            self._fh.truncate(0)
            fcntl.flock(self._fh, fcntl.LOCK_UN)
            self._fh.close()
            self._fh = None


def _run(session, desc: str, progress: bool) -> None:
    """Steps until the session's stage is done, with a progress bar; saves on the way out."""
    done, total, _, minutes = session.run_length()
    session.maybe_evaluate(force=done == 0)
    # a bar over steps, or over the stage's progress in per mille when minutes may end it first
    by_time = bool(minutes)
    bar = tqdm(total=1000 if by_time else total, initial=round(1000 * session.progress) if by_time else done,
               desc=desc + (f" ({minutes:g} min)" if by_time else ""), disable=not progress,
               unit="‰" if by_time else "it")
    try:
        while not session.done:
            out, _ = session.advance()
            bar.update(round(1000 * session.progress) - bar.n if by_time else 1)
            if session.step_count % 25 == 0 and not out.get("skipped"):
                bar.set_postfix(loss=f"{out['loss']:.4f}",
                                seen=f"{session.latest.get('seen_psnr', float('nan')):.1f}",
                                unseen=f"{session.latest.get('unseen_psnr', float('nan')):.1f}")
    finally:
        bar.close()
        session.save()
    session.maybe_evaluate(force=True)
    session.save()


def _report(session, run_dir: Path) -> None:
    from reconstruct.train.report import error_vs_time_table, plot_error_vs_time

    print(error_vs_time_table(session.log.read("eval")))
    print(f"wrote {plot_error_vs_time(run_dir)}", file=sys.stderr)


def train(scene_spec: str, run_dir: Path, config, *, progress: bool = True, stage: str = "1", stage2=None,
          allow_incomplete: bool = False):
    """Train until the run's steps or minutes are used up; returns the session. ``stage``: "1",
    "2" (continue the run's Stage I, or resume its Stage II) or "all"."""
    from app.run_setup import open_session

    if stage == "2":
        return train_stage2(run_dir, stage2, allow_incomplete=allow_incomplete, progress=progress)
    run_dir.mkdir(parents=True, exist_ok=True)
    with RunLock(run_dir):
        session = open_session(scene_spec, run_dir, config, progress=progress)
        if session.stage == 2:
            if stage == "1":
                raise RuntimeError(f"{run_dir}: this run is already in Stage II (use --stage 2 to continue it)")
        else:
            config = session.config
            if session.lpips_note:
                print(session.lpips_note, file=sys.stderr)
            if not session.use_normals:
                print("normal loss left out: the scene has no normal maps", file=sys.stderr)
            width, height = session.scene.image_size
            print(f"{session.model.num_gaussians} Gaussians, images {width}x{height}, "
                  f"target {config.iters} steps" + (f" or {config.minutes:g} min" if config.minutes else ""),
                  file=sys.stderr)
            _run(session, "stage I", progress)
        if stage == "all":
            session = _enter_stage2(session, run_dir, stage2, allow_incomplete)
            _run(session, "stage II", progress)
        _report(session, run_dir)
    return session


def _enter_stage2(session, run_dir: Path, stage2, allow_incomplete: bool):
    from reconstruct.stage2.config import Stage2Config
    from reconstruct.stage2.session import start_stage2
    from reconstruct.train.session import update_run_info

    if session.stage == 2:
        return session
    if isinstance(stage2, dict) or stage2 is None:
        stage2 = Stage2Config(**(stage2 or {}))
    session = start_stage2(session, stage2, allow_incomplete=allow_incomplete)
    update_run_info(run_dir, {"stage": 2, "stage2": session.stage2.to_dict(), "stage1_step": session.stage1_step})
    s2 = session.stage2
    print(f"Stage II: prior {session.prior.describe()}; {session.latest.get('unseen_views', 0)} unseen of "
          f"{len(session.selected_views)} candidate views (threshold {s2.visibility_threshold:g}); "
          f"{s2.iters} steps" + (f" or {s2.minutes:g} min" if s2.minutes else ""), file=sys.stderr)
    return session


def train_stage2(run_dir: Path, stage2_overrides: dict | None = None, *, allow_incomplete: bool = False,
                 progress: bool = True):
    """Continue a run with Stage II: from its finished Stage I checkpoint, or resume its Stage II.
    ``stage2_overrides``: Stage II settings given on the command line (the rest from the checkpoint
    when resuming, else the paper's defaults)."""
    from app.run_setup import check_run
    from reconstruct.data.load import load_scene
    from reconstruct.stage2.config import Stage2Config
    from reconstruct.stage2.session import Stage2Session
    from reconstruct.train.checkpoint import load_checkpoint
    from reconstruct.train.session import CHECKPOINT_NAME, TrainingSession

    if isinstance(stage2_overrides, Stage2Config):
        stage2_overrides = stage2_overrides.to_dict()
    overrides = dict(stage2_overrides or {})
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir}: no such run folder; train Stage I first (train --stage 1 --out {run_dir})")
    info = check_run(run_dir, "continue with Stage II")
    scene = load_scene(info["scene"], progress=progress)
    with RunLock(run_dir):
        state = load_checkpoint(run_dir / CHECKPOINT_NAME)
        if state.get("stage", 1) == 2:
            session = Stage2Session.from_state(scene, run_dir, state, stage2=overrides)
            session.log.truncate_after(session.step_count)
            print(f"resuming Stage II of {run_dir} at Stage II step {session.stage2_step}", file=sys.stderr)
        else:
            s1 = TrainingSession.from_state(scene, run_dir, state)
            s1.log.truncate_after(s1.step_count)
            session = _enter_stage2(s1, run_dir, Stage2Config(**overrides), allow_incomplete)
        _run(session, "stage II", progress)
        _report(session, run_dir)
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
