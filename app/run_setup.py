"""Open the TrainingSession of a run: a new one on a scene, or the one resumed from the run
folder's checkpoint (shared by ``train`` and the studio)."""

from __future__ import annotations

import sys
from pathlib import Path


def open_session(scene_spec: str, run_dir: str | Path | None = None, config=None, *, progress: bool = True):
    """``run_dir=None``: nothing is written (no checkpoint, no metrics log). A run folder with a
    checkpoint is resumed with the checkpoint's settings unless ``config`` is given; the records
    of its metrics log after the checkpoint's step are dropped (those steps are redone)."""
    from reconstruct.data.load import load_scene
    from reconstruct.train.checkpoint import CheckpointError
    from reconstruct.train.config import Stage1Config
    from reconstruct.train.session import CHECKPOINT_NAME, TrainingSession, write_run_info

    scene = load_scene(scene_spec, progress=progress)
    print(scene.summary(), file=sys.stderr)
    if run_dir is None:
        return TrainingSession(scene, config or Stage1Config(), None, scene_spec=scene_spec)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if (run_dir / CHECKPOINT_NAME).exists():
        try:
            session = TrainingSession.resume(scene, run_dir, config)
        except CheckpointError as exc:
            raise CheckpointError(f"{exc}; the run folder is left as it is (move the checkpoint away to start over)") from exc
        session.log.truncate_after(session.step_count)
        print(f"resuming {run_dir} at step {session.step_count}", file=sys.stderr)
        return session
    config = config or Stage1Config()
    session = TrainingSession(scene, config, run_dir, scene_spec=scene_spec)
    write_run_info(run_dir, scene_spec, config)
    return session


def check_run(run_dir: Path, what: str) -> dict:
    """The run's ``run.json`` after checking that ``run_dir`` is a training run with a checkpoint;
    ``what`` names the use in the error ("evaluate", "export")."""
    import json

    from reconstruct.train.checkpoint import CheckpointError
    from reconstruct.train.session import CHECKPOINT_NAME

    info_path = Path(run_dir) / "run.json"
    if not info_path.is_file():
        raise CheckpointError(f"{run_dir}: not a training run (no run.json)")
    if not (Path(run_dir) / CHECKPOINT_NAME).is_file():
        raise CheckpointError(f"{Path(run_dir) / CHECKPOINT_NAME}: no checkpoint to {what}")
    return json.loads(info_path.read_text())


def resume_run(run_dir: Path, info: dict):
    """The session of a checked run (``check_run``), resumed on its own scene and settings."""
    from reconstruct.data.load import load_scene
    from reconstruct.train.session import TrainingSession

    return TrainingSession.resume(load_scene(info["scene"], progress=False), run_dir)
