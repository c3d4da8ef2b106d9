"""Headless ``train``, ``eval`` and ``migrate`` commands (all through ``RunFolder``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from tqdm import tqdm

from reconstruct.run_folder import RunFolder, check_device


def _run(trainer, desc: str, progress: bool) -> None:
    """Steps until the trainer's stage is done, with a progress bar; saves on the way out."""
    done, total, _, minutes = trainer.run_length()
    trainer.maybe_evaluate(force=done == 0)
    # a bar over steps, or over the stage's progress in per mille when minutes may end it first
    by_time = bool(minutes)
    bar = tqdm(total=1000 if by_time else total, initial=round(1000 * trainer.progress) if by_time else done,
               desc=desc + (f" ({minutes:g} min)" if by_time else ""), disable=not progress,
               unit="‰" if by_time else "it")
    try:
        while not trainer.done:
            out, _ = trainer.advance()
            bar.update(round(1000 * trainer.progress) - bar.n if by_time else 1)
            if trainer.step_count % 25 == 0 and not out.get("skipped"):
                bar.set_postfix(_postfix(out, trainer.latest))
    finally:
        bar.close()
        trainer.save()
    trainer.maybe_evaluate(force=True)
    trainer.save()


def _postfix(out: dict, latest: dict) -> dict:
    """The progress bar's numbers: the loss and the PSNRs the run has (evaluation views, validation)."""
    shown = {"loss": f"{out['loss']:.4f}"}
    for key, name in (("seen_psnr", "seen"), ("unseen_psnr", "unseen"), ("val_psnr", "val")):
        if isinstance(latest.get(key), (int, float)):
            shown[name] = f"{latest[key]:.1f}"
    return shown


def _report(trainer, run: RunFolder) -> None:
    from reconstruct.train.report import error_vs_time_table, plot_error_vs_time

    print(error_vs_time_table(trainer.log.read("eval")))
    print(f"wrote {plot_error_vs_time(run.path)}", file=sys.stderr)


def _describe_stage1(trainer) -> None:
    if trainer.lpips_note:
        print(trainer.lpips_note, file=sys.stderr)
    if not trainer.data.use_normals:
        print("normal loss left out: the scene has no normal maps", file=sys.stderr)
    if not trainer.scene.eval_views:
        print(f"the scene has no evaluation views (no ground truth from other cameras): unseen-view metrics are "
              f"left out; validation on {trainer.val_kind}: frames {trainer.val_frames}", file=sys.stderr)
    width, height = trainer.scene.image_size
    print(f"{trainer.state.num_gaussians} Gaussians, images {width}x{height}, {len(trainer.data)} training frames, "
          f"target {trainer.plan.describe()}", file=sys.stderr)
    if trainer.refines_poses and not trainer.config.pose_refinement:
        print("pose refinement on: the frames' poses are prepare's fit of a video or a folder of frames (--set "
              "pose_refinement_prepared=false keeps them as fitted)", file=sys.stderr)


def _enter_stage2(trainer, run: RunFolder, stage2, allow_incomplete: bool):
    from reconstruct.stage2.config import Stage2Config

    if trainer.stage == 2:
        return trainer
    if isinstance(stage2, dict) or stage2 is None:
        stage2 = Stage2Config(**(stage2 or {}))
    plan = run.start_stage2(trainer, stage2, allow_incomplete=allow_incomplete)
    print(f"Stage II: {plan.describe()}", file=sys.stderr)
    return trainer


def train(scene_spec: str, run_dir: Path, config, *, progress: bool = True, stage: str = "1", stage2=None,
          allow_incomplete: bool = False, device: str | None = None):
    """Train until the run's steps or minutes are used up; returns the trainer. ``stage``: "1",
    "2" (continue the run's Stage I, or resume its Stage II) or "all". ``device``: "cpu" or
    "cuda", or None for the one the run (or ``config``) names (``run_folder.placed_on``)."""
    check_device(device)  # before the scene is loaded or built
    run = RunFolder(run_dir)
    if stage == "2":
        return train_stage2(run_dir, stage2, allow_incomplete=allow_incomplete, progress=progress, device=device)
    with run.lock():
        trainer = run.open(scene_spec, config, progress=progress, device=device)
        if trainer.stage == 2:
            if stage == "1":
                raise RuntimeError(f"{run_dir}: this run is already in Stage II (use --stage 2 to continue it)")
        else:
            _describe_stage1(trainer)
            _run(trainer, "stage I", progress)
        if stage == "all":
            _enter_stage2(trainer, run, stage2, allow_incomplete)
            _run(trainer, "stage II", progress)
        _report(trainer, run)
    return trainer


def train_stage2(run_dir: Path, stage2_overrides: dict | None = None, *, allow_incomplete: bool = False,
                 progress: bool = True, device: str | None = None):
    """Continue a run with Stage II: from its finished Stage I checkpoint, or resume its Stage II.
    ``stage2_overrides``: Stage II settings given on the command line (the rest from the checkpoint
    when resuming, else the paper's defaults)."""
    from reconstruct.stage2.config import Stage2Config

    if isinstance(stage2_overrides, Stage2Config):
        stage2_overrides = stage2_overrides.to_dict()
    overrides = dict(stage2_overrides or {})
    run = RunFolder(run_dir)
    if not run.path.is_dir():
        raise FileNotFoundError(f"{run_dir}: no such run folder; train Stage I first (train --stage 1 --out {run_dir})")
    run.check("continue with Stage II")
    with run.lock():
        trainer = run.resume_training(stage2_overrides=overrides, progress=progress, device=device)
        if trainer.stage == 2:
            print(f"resuming Stage II of {run_dir} at Stage II step {trainer.stage_step}", file=sys.stderr)
        else:
            _enter_stage2(trainer, run, Stage2Config(**overrides), allow_incomplete)
        _run(trainer, "stage II", progress)
        _report(trainer, run)
    return trainer


def evaluate(run_dir: Path, *, as_json: bool, scale: int = 1, novel: str | None = None, novel_frames: int = 8) -> int:
    """Seen / unseen metrics of a run on its scene's held-out views, rendered at ``scale`` x the
    scene's resolution (coverage: hole fraction and alpha IoU at that scale). ``novel``: also the
    coverage in that novel pose sequence (``novel_frames`` poses) against the ground truth of a
    synthetic scene (``reconstruct.train.novel_coverage``)."""
    import torch

    from reconstruct.train.evaluate import evaluate_views
    from reconstruct.train.report import plot_error_vs_time

    if novel is not None and novel_frames < 2:
        raise ValueError(f"--novel-frames must be at least 2, found {novel_frames}")
    run = RunFolder(run_dir)
    info = run.check("evaluate")
    trainer = run.resume()
    novel_result = None
    if novel is not None:
        from reconstruct.train.novel_coverage import novel_coverage, novel_views

        views = novel_views(trainer.scene, trainer.state.body, novel, novel_frames)
        novel_rows, novel_summary = novel_coverage(trainer.state, views, trainer.background, scale=scale)
        novel_result = {"sequence": novel, "frames": novel_frames, **novel_summary, "views": novel_rows}
    with torch.no_grad():
        rows, summary = evaluate_views(trainer.state, trainer.scene, trainer.background, lpips=trainer.lpips,
                                       scale=scale)
    result = {"run": str(run_dir), "scene": info["scene"], "step": trainer.step_count, "scale": scale, **summary,
              "views": rows}
    if novel_result is not None:
        result["novel"] = novel_result
    if trainer.lpips_note:
        result["note"] = trainer.lpips_note
    if as_json:
        print(json.dumps(result, indent=1))
    else:
        for r in rows:
            holes = "" if r.get("hole_fraction") is None else f"  holes {100 * r['hole_fraction']:5.2f}%"
            print(f"{r['view']:<14} frame {r['frame']:>3} {'seen' if r['seen'] else 'unseen':<7} "
                  f"PSNR {r['psnr']:6.2f}  SSIM {r['ssim']:.4f}  alpha IoU {r['alpha_iou']:.4f}{holes}")
        print(" ".join(f"{k}={v:.4f}" for k, v in summary.items() if v is not None))
        if novel_result is not None:
            for r in novel_result["views"]:
                garment = ("" if r["garment_hole_fraction"] is None
                           else f"  garment holes {100 * r['garment_hole_fraction']:5.2f}%")
                print(f"{novel} {r['index']:>3} azimuth {r['azimuth_deg']:5.1f}  alpha IoU {r['alpha_iou']:.4f}  "
                      f"holes {100 * r['hole_fraction']:5.2f}%{garment}")
            print(" ".join(f"{k}={v:.4f}" for k, v in novel_result.items()
                           if isinstance(v, float)))
    try:
        print(f"wrote {plot_error_vs_time(run_dir)}", file=sys.stderr)
    except ValueError as exc:
        print(f"no error-vs-time plot: {exc}", file=sys.stderr)
    return 0


def migrate(run_dir: Path, *, trust: bool) -> int:
    run = RunFolder(run_dir)
    run.info()
    with run.lock():
        done = run.migrate(trust=trust)
    for path in done:
        print(f"converted {path} to the current checkpoint format")
    if not done:
        print(f"{run_dir}: its checkpoints are already in the current format")
    return 0
