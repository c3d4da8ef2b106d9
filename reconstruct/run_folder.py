"""RunFolder: one training run's folder and everything that touches it as a whole.

Files: ``checkpoint.pt`` (the running stage), ``checkpoint_stage1.pt`` (Stage I's, kept when
Stage II starts), ``run.json`` (scene, stage, settings, versions), ``metrics.jsonl`` (training and
evaluation records), ``.lock`` (held by the one process training into the folder), ``edits/``
(the user's edits: ``edits.json`` plus texel masks, ``reconstruct.edits.store``; applied to the
avatar of every trainer opened from a checkpoint -- train, eval, export, the studio).

It owns the exclusive lock (``lock()``), the run info, opening a trainer -- new, or resumed with
the single dispatch on the checkpoint's stage -- and the switch to Stage II. ``train``, ``eval``,
``export``, ``demo`` and the studio all go through it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from pathlib import Path

import torch

from .atomic import atomic_output
from .train.checkpoint import (CHECKPOINT_NAME, STAGE1_CHECKPOINT_NAME, CheckpointError, garment_layer_of,
                               load_checkpoint, migrate_checkpoint)
from .train.config import Stage1Config
from .train.trainer import Trainer

INFO_NAME = "run.json"
METRICS_NAME = "metrics.jsonl"
LOCK_NAME = ".lock"


def check_device(device: str | None) -> None:
    """Raises when ``device`` asks for CUDA on a machine without it (before anything is loaded)."""
    if device == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("--device cuda: CUDA is not available on this machine")


def placed_on(config: Stage1Config, device: str | None, where: str) -> Stage1Config:
    """``config`` to run on ``device`` ("cpu" or "cuda"; None: the device the settings name). The
    device is where this process runs, not part of the run: a run trained on a GPU opens on a
    machine without one, on the CPU (with a note); asking for CUDA where there is none is an error."""
    check_device(device)
    want = device or config.device
    if want == "cuda" and not torch.cuda.is_available():
        print(f"{where}: trained on CUDA; this machine has none, so it runs on the CPU", file=sys.stderr)
        want = "cpu"
    return config if want == config.device else dataclasses.replace(config, device=want)


class RunLockedError(RuntimeError):
    pass


class RunLock:
    """Refuses a second training process on the same run folder: an exclusive ``flock`` on
    ``RUN/.lock`` held for the whole run (the kernel drops it when the process dies, even by
    SIGKILL), with the holder's pid written inside for the message."""

    def __init__(self, run_dir: Path) -> None:
        self.path = Path(run_dir) / LOCK_NAME
        self._fh = None

    @property
    def held(self) -> bool:
        return self._fh is not None

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

    release = __exit__


class RunFolder:
    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    @property
    def checkpoint(self) -> Path:
        return self.path / CHECKPOINT_NAME

    @property
    def stage1_checkpoint(self) -> Path:
        return self.path / STAGE1_CHECKPOINT_NAME

    @property
    def info_path(self) -> Path:
        return self.path / INFO_NAME

    @property
    def has_checkpoint(self) -> bool:
        return self.checkpoint.is_file()

    def lock(self) -> RunLock:
        """The folder's exclusive lock (a context manager); the folder is made when missing."""
        self.path.mkdir(parents=True, exist_ok=True)
        return RunLock(self.path)

    # ----- run info ------------------------------------------------------------------------
    def info(self) -> dict:
        if not self.info_path.is_file():
            raise CheckpointError(f"{self.path}: not a training run (no {INFO_NAME})")
        try:
            info = json.loads(self.info_path.read_text())
        except (OSError, ValueError) as exc:
            raise CheckpointError(f"{self.info_path}: not readable as JSON ({exc})") from exc
        if not isinstance(info, dict) or not isinstance(info.get("scene"), str):
            raise CheckpointError(f"{self.info_path}: expected a JSON object with a 'scene' entry")
        return info

    def update_info(self, fields: dict) -> None:
        """Sets ``fields`` in ``run.json`` (written atomically)."""
        info = json.loads(self.info_path.read_text()) if self.info_path.exists() else {}
        info.update(fields)
        with atomic_output(self.info_path) as tmp:
            tmp.write_text(json.dumps(info, indent=1))

    def check(self, what: str) -> dict:
        """The run info after checking that this is a training run with a checkpoint; ``what``
        names the use in the error ("evaluate", "export")."""
        info = self.info()
        if not self.has_checkpoint:
            raise CheckpointError(f"{self.checkpoint}: no checkpoint to {what}")
        return info

    # ----- trainers -------------------------------------------------------------------------
    def new_trainer(self, scene, config: Stage1Config, scene_spec: str) -> Trainer:
        """A new run in this folder (Stage I from scratch); writes the run info. The scene spec is
        recorded with its defaults written out (``canonical_scene_spec``), so the run still names
        the same scene when a later version changes them."""
        from .data.load import canonical_scene_spec

        scene_spec = canonical_scene_spec(scene_spec)
        self.path.mkdir(parents=True, exist_ok=True)
        trainer = Trainer(scene, config, self.path, scene_spec=scene_spec)
        self.update_info({"scene": scene_spec, "stage": 1, "config": config.to_dict(),
                          "python": sys.version.split()[0], "torch": torch.__version__})
        return trainer

    def resume(self, scene=None, config: Stage1Config | None = None, stage2_overrides: dict | None = None,
               *, progress: bool = False, device: str | None = None) -> Trainer:
        """The trainer of this folder's checkpoint (read once), on its own scene unless ``scene``
        is given, with its own settings unless ``config`` / ``stage2_overrides`` replace them:
        Stage I, or the Stage II plan when the run is in Stage II. Nothing in the folder is
        changed (``eval``, ``export``). ``device``: where to run (``placed_on``)."""
        from .stage2.plan import restore_stage2

        state = load_checkpoint(self.checkpoint)
        if scene is None:
            scene = self.load_scene(progress=progress)
        cfg = placed_on(config or Stage1Config.from_dict(state["config"]), device, str(self.path))
        stage = int(state.get("stage", 1))
        if stage == 2:
            plan = lambda t: restore_stage2(t, state["plan"], stage2_overrides)  # noqa: E731
        elif stage == 1:
            plan = None
        else:
            raise CheckpointError(f"{self.checkpoint}: unknown stage {stage}")
        # the checkpoint's garment layer (none in one written before the layer existed), not one
        # built anew from the config and the masks
        layer = garment_layer_of(state, str(self.checkpoint))
        trainer = Trainer(scene, cfg, self.path, scene_spec=state.get("scene_spec"), plan=plan, garment_layer=layer)
        trainer.load_state_dict(state, str(self.checkpoint))
        trainer.state.edits = self.load_edits(trainer.state.model).applied
        return trainer

    # ----- edits ------------------------------------------------------------------------------
    @property
    def edits_path(self) -> Path:
        from .edits.store import edits_path

        return edits_path(self.path)

    def load_edits(self, model):
        """The folder's edits (``StoredEdits``: applied list, redo stack); ``EditsError`` naming
        the file when it is malformed (nothing is written)."""
        from .edits.store import load_edits

        return load_edits(self.path, model.num_gaussians, model)

    def resume_training(self, scene=None, config: Stage1Config | None = None, stage2_overrides: dict | None = None,
                        *, progress: bool = False, device: str | None = None) -> Trainer:
        """``resume`` to train on: the metrics log's records after the checkpoint's step are
        dropped (those steps are redone). Hold the lock."""
        trainer = self.resume(scene, config, stage2_overrides, progress=progress, device=device)
        trainer.log.truncate_after(trainer.step_count)
        if trainer.stage == 2 and trainer.plan.sync_visibility(trainer.state):
            print(f"{self.path}: the painted visibility changed: Stage II's views and propagated colours redone",
                  file=sys.stderr)
        return trainer

    def load_scene(self, *, progress: bool = False):
        """The scene the run was trained on (its recorded spec, ``recorded_scene_spec``)."""
        from .data.load import load_scene, recorded_scene_spec

        return load_scene(recorded_scene_spec(self.info()["scene"]), progress=progress)

    def open(self, scene_spec: str, config: Stage1Config | None = None, *, progress: bool = True,
             device: str | None = None) -> Trainer:
        """Resume the folder's run when it has a checkpoint -- on the run's own scene, with the
        checkpoint's settings unless ``config`` is given -- else start one on ``scene_spec``;
        ``device`` as in ``placed_on``."""
        from .data.load import canonical_scene_spec, load_scene, recorded_scene_spec

        resuming = self.has_checkpoint
        if resuming:
            recorded = recorded_scene_spec(self.info()["scene"])
            if canonical_scene_spec(scene_spec) != recorded:
                print(f"resuming on the run's own scene {recorded} (not {scene_spec})", file=sys.stderr)
            scene_spec = recorded
        scene = load_scene(scene_spec, progress=progress)
        print(scene.summary(), file=sys.stderr)
        if resuming:
            try:
                trainer = self.resume_training(scene, config, device=device)
            except CheckpointError as exc:
                raise CheckpointError(f"{exc}; the run folder is left as it is (move the checkpoint away to start "
                                      f"over)") from exc
            print(f"resuming {self.path} at step {trainer.step_count}", file=sys.stderr)
            return trainer
        return self.new_trainer(scene, placed_on(config or Stage1Config(), device, str(self.path)), scene_spec)

    def start_stage2(self, trainer: Trainer, settings, *, allow_incomplete: bool = False):
        """Switch ``trainer`` (this folder's, in Stage I) to Stage II and record it in the run info."""
        from .stage2.plan import start_stage2

        plan = start_stage2(trainer, settings, allow_incomplete=allow_incomplete)
        self.update_info({"stage": 2, "stage2": plan.settings.to_dict(), "stage1_step": trainer.stage_starts[2]})
        return plan

    def migrate(self, *, trust: bool) -> list[Path]:
        """Convert the folder's checkpoints written by an earlier version (format 1) to the current
        format; ``trust`` says the user trusts them (reading format 1 can run code)."""
        done = []
        for path in (self.checkpoint, self.stage1_checkpoint):
            if path.is_file() and migrate_checkpoint(path, trust=trust):
                done.append(path)
        return done
