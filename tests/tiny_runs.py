"""The smallest real run the CLI can train, for tests of what reads run folders (export, edit, eval,
checkpoint safety, resume): a 3-frame 48 px synthetic scene, a 32 px Gaussian map, a 16-wide decoder."""

from __future__ import annotations

from pathlib import Path

TINY_SCENE = "synthetic:seed=1,frames=3,size=48,azimuths=8,eval_frames=1,texture_size=128"


def tiny_train_args(run: Path, iters: int = 3, *extra: str, scene: str = TINY_SCENE) -> list[str]:
    """``wonderhuman-studio`` arguments that train ``iters`` Stage I steps of a tiny avatar into ``run``."""
    return ["train", "--scene", str(scene), "--out", str(run), "--iters", str(iters), "--gaussian-res", "32",
            "--hidden", "16", "--quiet", "--set", "crop_margin=4", *extra]


def train_tiny(run: Path, iters: int = 3, *extra: str, scene: str = TINY_SCENE) -> Path:
    """Trains the tiny run in-process (``app.cli.main``); returns ``run``."""
    from app.cli import main

    code = main(tiny_train_args(run, iters, *extra, scene=scene))
    assert code == 0, f"training the tiny run into {run} exited {code}"
    return run
