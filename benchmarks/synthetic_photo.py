"""A synthetic scene as a photo: the unseen side of a one-photo avatar, scored against ground truth.

A user's photo has one frame, one view and no normal maps (``prepare`` writes none). A synthetic
scene with ``frames=1`` has the one frame and view, and every evaluation azimuth's ground truth;
trained without its normal maps it is a photo with an answer sheet for its back.

    # Stage I as on a prepared photo (the arguments are wonderhuman-studio's; normal maps left out)
    OMP_NUM_THREADS=1 python benchmarks/synthetic_photo.py train --scene "synthetic:seed=2,clothing=coat,frames=1" \\
        --out RUN --stage 1 --iters 450 --threads 1 --set threads=1
    wonderhuman-studio eval RUN --json                      # seen / unseen PSNR, holes, IoU

    # Stage I's finish (the seen recount and the unseen fills) run again on the checkpoint, in
    # memory, with the code as it is now; then the same evaluation. Nothing is written: a change
    # to the fills is compared on the same trained avatar
    OMP_NUM_THREADS=1 python benchmarks/synthetic_photo.py refill RUN [RUN ...] [--set KEY=VALUE ...]

``--set`` overrides Stage I settings for the finish (a run keeps the settings it recorded; a
setting newer than the run is off for it, so give it here to measure it on an older run).
``refill`` prints one row per run (seen and unseen PSNR, and the unseen PSNR per azimuth, the
mean over the view's frames). It works on any Stage I run folder, photos' and videos' alike (on a
real photo's run it rereads the scene by the path the run recorded).
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def train(argv: list[str]) -> int:
    """``wonderhuman-studio`` with every scene's normal maps left out of training."""
    from app.cli import main
    from reconstruct.data.scene import Scene

    kept = Scene.has_normals
    Scene.has_normals = property(lambda self: False)
    try:
        return main(argv)
    finally:
        Scene.has_normals = kept


def refill(run: str, overrides: list[str] | None = None) -> dict:
    """Re-run Stage I's finish on ``run``'s checkpoint in memory (its Stage I settings with
    ``overrides``, ``KEY=VALUE`` as ``--set`` takes them) and evaluate it."""
    import torch

    from reconstruct import config as config_layer
    from reconstruct.run_folder import RunFolder
    from reconstruct.train.config import Stage1Config

    trainer = RunFolder(run).resume()
    if overrides:
        sets = config_layer.parse_overrides(Stage1Config, overrides, "Stage I", "--set")
        trainer.plan.settings = config_layer.with_overrides(trainer.plan.settings, sets)
    trainer.plan.finish(trainer)
    with torch.no_grad():
        rows, summary = trainer.evaluate()
    by_az = defaultdict(list)
    for r in rows:
        if not r["seen"]:
            by_az[r["azimuth_deg"]].append(r["psnr"])
    return {"run": run, "seen": summary["seen_psnr"], "unseen": summary["unseen_psnr"],
            "unseen_by_azimuth": {az: sum(v) / len(v) for az, v in sorted(by_az.items())}}


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("train", "refill"):
        print(__doc__)
        return 2
    if argv[0] == "train":
        return train(argv)
    import torch

    torch.set_num_threads(1)
    print("| run | seen | unseen | unseen by azimuth |")
    print("|---|---|---|---|")
    runs, sets, rest = [], [], list(argv[1:])
    while rest:
        a = rest.pop(0)
        if a == "--set":
            if not rest:
                print("--set needs KEY=VALUE", file=sys.stderr)
                return 2
            sets.append(rest.pop(0))
        else:
            runs.append(a)
    for run in runs:
        r = refill(run, sets)
        azs = " ".join(f"{az:.0f}: {p:.2f}" for az, p in r["unseen_by_azimuth"].items())
        print(f"| {run} | {r['seen']:.3f} | {r['unseen']:.3f} | {azs} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
