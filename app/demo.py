"""The main job on the built-in demo scene, headless: build (or load) the synthetic scene, train
Stage I for a few minutes with the error-vs-time log and seen/unseen evaluations, then Stage II
(built-in prior) for a few more, then write the scene's contact sheet and a comparison sheet of the
avatar against the ground truth."""

from __future__ import annotations

from pathlib import Path

from app.comparison import write_comparison_sheet
from app.contact_sheet import write_contact_sheet
from app.train_cmd import train
from reconstruct.stage2.config import Stage2Config
from reconstruct.train.config import Stage1Config


def run_demo(spec: str, out: Path, *, minutes: float = 3.0, stage2_minutes: float = 2.0,
             threads: int | None = None, device: str | None = None) -> int:
    """``device``: "cpu" or "cuda" (None: the CPU for a new run, a resumed run's own device)."""
    out.mkdir(parents=True, exist_ok=True)
    run = out / "run"
    config = Stage1Config(iters=10 ** 7, minutes=minutes, eval_every_seconds=max(15.0, 10.0 * minutes), threads=threads)
    if stage2_minutes > 0:
        stage2 = Stage2Config(iters=10 ** 7, minutes=stage2_minutes)
        trainer = train(spec, run, config, stage="all", stage2=stage2, allow_incomplete=True, device=device)
    else:
        trainer = train(spec, run, config, device=device)
    print(f"contact sheet: {write_contact_sheet(trainer.scene, out / 'contact_sheet.png')}")
    print(f"comparison: {write_comparison_sheet(trainer.avatar(), out / 'comparison.png')}")
    print(f"error against run time: {run / 'error_vs_time.png'}; metrics: {run / 'metrics.jsonl'}")
    return 0
