"""Trainer: runs a stage plan on an avatar state.

It owns the loop and everything a step needs around it: the optimisers (built from the plan's
parameter groups), the learning-rate schedule over the stage's progress, the guards against
non-finite numbers, the clocks (whole run and current stage), evaluation and checkpoint timing,
the metrics log, and the snapshots the renderer draws. What is trained lives in ``AvatarState``;
how a stage trains it lives in its ``StagePlan`` (Stage I: ``Stage1Plan``; Stage II:
``reconstruct.stage2.plan.Stage2Plan``, switched to with ``begin``).

Garment layer: with ``avatar.garment_layer`` "auto" or "on" the trainer builds the layer when it
starts (``garment_layer_for`` on the training frames' masks); a checkpoint's layer (its geometry is
saved with it) replaces the model's before the checkpoint is loaded.

Files: the trainer writes ``checkpoint.pt`` and appends to ``metrics.jsonl`` in ``run_dir`` when it
has one; the run folder itself (lock, run info, resume) is ``reconstruct.run_folder.RunFolder``.
"""

from __future__ import annotations

import copy
import math
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..avatar.garment_layer import GarmentLayer, garment_layer_for
from ..avatar.model import AvatarModel
from ..avatar.state import AvatarState
from ..body.pose import BodyPose
from ..data.scene import Scene
from ..metrics import load_lpips_or_none
from ..snapshot import Snapshot, SnapshotBox
from .checkpoint import CHECKPOINT_NAME, CheckpointError, garment_layer_of, plain_scalars, save_checkpoint
from .config import Stage1Config
from .data import TrainingData
from .evaluate import evaluate_views
from .metrics_log import MetricsLog
from .plan import Stage1Plan, StagePlan
from .row_adam import RowAdam
from .validation import holdout_frames, resolve_holdout, validate_frames

GOOD_STATE_EVERY = 100  # steps between in-memory copies of the last good state
FROM_CONFIG = "config"  # Trainer(garment_layer=...): build the layer the config asks for


@dataclass
class TrainedAvatar:
    """A trained avatar as exports and viewers see it: its state, the scene it was trained on and
    where training stood. ``Trainer.avatar()`` is the live one; ``Trainer.frozen()`` a copy that no
    longer changes (exports while training goes on)."""

    state: AvatarState
    scene: Scene
    stage: int = 1
    step: int = 0
    metrics: dict = field(default_factory=dict)
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def body(self):
        return self.state.body

    def _meta(self) -> dict:
        return {"stage": self.stage, "step": self.step, "metrics": dict(self.metrics)}

    def make_snapshot(self, space: str = "observation", frame_index: int = 0) -> Snapshot:
        return self.state.snapshot(space, frame_index, **self._meta())

    def snapshot_at_pose(self, pose: BodyPose, frame_index: int = 0) -> Snapshot:
        return self.state.snapshot_at_pose(pose, frame_index, **self._meta())


# scenes whose poses ``prepare`` fitted to more than one frame (meta["source"], scene_io)
PREPARED_SOURCES = ("video", "folder")


def refines_poses(scene: Scene, config: Stage1Config, training_frames: int) -> bool:
    """Whether Stage I refines the frames' poses: asked for (``pose_refinement``), or a scene
    ``prepare`` fitted to a video or a folder of frames (``pose_refinement_prepared``) with more
    than one training frame (a single frame's correction is centred away, ``row_adam.py``)."""
    if config.pose_refinement:
        return True
    return (config.pose_refinement_prepared and training_frames > 1
            and scene.meta.get("source") in PREPARED_SOURCES)


def _row_adam_state(saved: dict, frames: int) -> bool:
    """Whether a saved pose optimiser state is RowAdam's for ``frames`` frames (a step count per
    row), not the single Adam of runs before it."""
    inner = saved.get("state") or {}
    return all(torch.is_tensor(s.get("step")) and tuple(s["step"].shape) == (frames,) for s in inner.values())


class Trainer:
    def __init__(self, scene: Scene, config: Stage1Config | None = None, run_dir: str | Path | None = None, *,
                 scene_spec: str | None = None,
                 plan: StagePlan | Callable[["Trainer"], StagePlan] | None = None,
                 garment_layer: GarmentLayer | None | str = FROM_CONFIG) -> None:
        """A new avatar on ``scene``, trained by ``plan`` (default: Stage I), or -- ``plan`` a
        function of the trainer -- the plan a checkpoint is about to be loaded into.
        ``garment_layer``: the layer the config asks for (``avatar.garment_layer``, from the
        training frames' masks), or this one (None: none; a checkpoint's: ``garment_layer_of``)."""
        self.scene = scene
        self.config = config = config or Stage1Config()
        self.scene_spec = scene_spec or scene.name
        self.device = torch.device(config.device)
        if config.threads:
            torch.set_num_threads(config.threads)
        self.holdout = resolve_holdout(scene, config.holdout)
        self.val_frames = holdout_frames(len(scene.frames), self.holdout)
        training_frames = [i for i in range(len(scene.frames)) if i not in set(self.val_frames)]
        torch.manual_seed(config.seed)
        self.rng = np.random.default_rng(config.seed)
        body = scene.body_model()
        if isinstance(garment_layer, str):  # (no random numbers drawn: the model starts as without a layer)
            if garment_layer != FROM_CONFIG:
                raise ValueError(f"Trainer: garment_layer must be a GarmentLayer, None or {FROM_CONFIG!r}, "
                                 f"found {garment_layer!r}")
            garment_layer = garment_layer_for(body, [scene.frames[i] for i in training_frames],
                                              config.avatar.garment_layer, f"scene {scene.name}",
                                              row_step=config.avatar.garment_layer_step,
                                              one_tube_filter=config.avatar.garment_filter_one_tube)
            if garment_layer is not None:
                print(garment_layer.describe(), file=sys.stderr)
        model = AvatarModel(body, config.avatar, layer=garment_layer).to(self.device)
        self.refines_poses = refines_poses(scene, config, len(training_frames))
        self.state = AvatarState(body, model, [f.pose for f in scene.frames], refine_poses=self.refines_poses)
        self.background = torch.tensor(config.background, dtype=torch.float32, device=self.device)
        # one frame's correction per step: each row its own Adam (row_adam.py)
        self.pose_optimizer = (RowAdam([self.state.pose_delta], lr=config.lr_pose, centre=config.pose_refinement_centre)
                               if self.refines_poses else None)
        wanted = bool(config.lpips_backbone or config.lpips_lin)
        self.lpips, reason = load_lpips_or_none({"net": config.lpips_net, "backbone_path": config.lpips_backbone,
                                                 "lin_path": config.lpips_lin} if wanted else None)
        if wanted and self.lpips is None:  # weights were asked for: a problem with them is an error
            raise ValueError(f"LPIPS weights (lpips_backbone={config.lpips_backbone!r}, "
                             f"lpips_lin={config.lpips_lin!r}): {reason}")
        self.lpips_note = None if self.lpips is not None else "LPIPS left out: no weights given"
        if self.lpips is not None:
            self.lpips = self.lpips.to(self.device).eval()
            for p in self.lpips.parameters():
                p.requires_grad_(False)
        self.data = TrainingData(scene, self.background, config.crop_margin, training_frames)
        if not self.val_frames and not scene.eval_views:  # nothing held out (one frame): report the fit
            self.val_frames = [self.data.frames[int(k)] for k in np.linspace(0, len(self.data) - 1,
                                                                              min(4, len(self.data)))]
            self.val_kind = "training-view fit"
        else:
            self.val_kind = "held-out frames"
        # clocks: the whole run, and the running stage
        self.step_count = 0
        self.elapsed = 0.0  # seconds spent in steps and evaluations, accumulated over resumes
        self.stage_step = 0
        self.stage_elapsed = 0.0
        self.stage_starts: dict[int, int] = {1: 0}  # stage -> run step at which it started
        self.kind_counts: dict[str, int] = {}
        self.epoch_order: list[int] = []
        self.snapshots = SnapshotBox()
        self.latest: dict = {}
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.log = MetricsLog(self.run_dir / "metrics.jsonl") if self.run_dir else None
        self._last_eval = -math.inf
        self._last_ckpt = 0.0
        self.nonfinite_skipped = 0  # steps skipped for a non-finite loss or gradient
        self.restored_states = 0  # times a non-finite parameter brought back the last good state
        self._last_good: dict | None = None
        self.plan: StagePlan | None = None
        if callable(plan):
            plan = plan(self)
        self.begin(plan or Stage1Plan(config), fresh=False)

    # ----- the plan --------------------------------------------------------------------------
    def begin(self, plan: StagePlan, *, fresh: bool = True) -> None:
        """Train by ``plan`` from now on: its optimiser on the same avatar state. ``fresh``: a new
        stage starts here (its clocks, step mix and frame order start over, as a stage run on
        its own would)."""
        if fresh:
            self.stage_starts[plan.stage] = self.step_count
            self.stage_step, self.stage_elapsed = 0, 0.0
            self.rng = np.random.default_rng(self.config.seed)
            self.epoch_order = []
            self.kind_counts = {}
            self._last_eval = self._last_ckpt = self.elapsed
        self.plan = plan
        self.optimizer = torch.optim.Adam(plan.param_groups(self.state))
        self.base_lrs = [g["lr"] for g in self.optimizer.param_groups]
        self._last_good = None

    @property
    def stage(self) -> int:
        return self.plan.stage

    @property
    def model(self) -> AvatarModel:
        return self.state.model

    @property
    def progress(self) -> float:
        """Fraction of the running stage done: whichever of its steps or minutes ends first."""
        return self.plan.settings.progress(self.stage_step, self.stage_elapsed)

    @property
    def done(self) -> bool:
        return self.progress >= 1.0

    def run_length(self) -> tuple[int, int, float, float | None]:
        """(steps taken, steps planned, seconds spent, minutes planned) of the running stage. The
        stage's seconds are training time: evaluations count in the run's clock (``elapsed``, the
        x axis of the error-vs-time report) but not against a ``--minutes`` budget, so a short run
        on a busy machine is not spent evaluating."""
        s = self.plan.settings
        return self.stage_step, s.iters, self.stage_elapsed, s.minutes

    def next_frame(self) -> int:
        """The next training frame: every training frame once per epoch, in a random order."""
        if not self.epoch_order:
            frames = self.data.frames
            self.epoch_order = [frames[int(j)] for j in self.rng.permutation(len(frames))]
        return int(self.epoch_order.pop())

    # ----- one step ----------------------------------------------------------------------------
    def step(self) -> dict:
        t0 = time.perf_counter()
        was_done = self.done
        kind = self.plan.next_kind(self.rng)
        mult = self.plan.settings.lr_schedule().value(self.progress)
        for g, base in zip(self.optimizer.param_groups, self.base_lrs):
            g["lr"] = base * mult
        outcome = self.plan.steps[kind](self)
        taken = False
        if not outcome.skipped:
            loss = outcome.loss()
            optimizers = [self.optimizer] + ([self.pose_optimizer] if outcome.refine_poses else [])
            taken = self._guarded_update(loss, optimizers)
        self.kind_counts[kind] = self.kind_counts.get(kind, 0) + 1
        self.step_count += 1
        self.stage_step += 1
        dt = time.perf_counter() - t0
        self.elapsed += dt
        self.stage_elapsed += dt
        if not self.done:  # the plan's acts within its stage (its clock counts them)
            t1 = time.perf_counter()
            note = self.plan.after_step(self)
            spent = time.perf_counter() - t1
            self.elapsed += spent
            self.stage_elapsed += spent
            self._plan_note(note)
        elif not was_done:
            self._finish_stage()
        if not taken:
            return self._skipped_step(kind, outcome)
        if outcome.after_update is not None:
            outcome.after_update()
        out = {"loss": float(loss.detach()), **{k: float(v.detach()) for k, v in outcome.terms.items()},
               "frame": outcome.frame, **outcome.info, "step_kind": kind, "stage_step": self.stage_step,
               **self.plan.status(self.stage_step)}
        self.latest.update(out)
        return out

    def _finish_stage(self) -> None:
        """The plan's last act, once, when its stage has used up its steps or minutes (before the
        final evaluation and checkpoint); its time counts in the run's clock, not the stage's."""
        t0 = time.perf_counter()
        note = self.plan.finish(self)
        self.elapsed += time.perf_counter() - t0
        self._plan_note(note)

    @staticmethod
    def _plan_note(note: str | None) -> None:
        if note:
            print(note, file=sys.stderr)

    def _skipped_step(self, kind: str, outcome) -> dict:
        """A step whose numbers were not finite: nothing was changed (or the last good state was
        restored); the step still counts so a run cannot loop forever on a bad frame."""
        self.nonfinite_skipped += 1
        bad = {k: float(v.detach()) for k, v in outcome.terms.items()}
        print(f"step {self.step_count}: non-finite loss or gradient on frame {outcome.frame} ({bad}); step skipped "
              f"({self.nonfinite_skipped} so far)", file=sys.stderr)
        self.latest.update({"nonfinite_skipped": self.nonfinite_skipped, "restored_states": self.restored_states})
        return {"skipped": True, "frame": outcome.frame, "step_kind": kind, "nonfinite_skipped": self.nonfinite_skipped,
                "restored_states": self.restored_states}

    # ----- guards against non-finite numbers -------------------------------------------------
    def _optimizers(self) -> list:
        return [self.optimizer] + ([self.pose_optimizer] if self.pose_optimizer is not None else [])

    def _guarded_update(self, loss: torch.Tensor, optimizers: list) -> bool:
        """Backward and step unless the loss or a gradient is non-finite; after the step, a
        non-finite parameter restores the last good state. False when the step was not taken."""
        if not torch.isfinite(loss):
            return False
        for opt in self._optimizers():
            opt.zero_grad(set_to_none=True)
        loss.backward()
        params = [p for g in self.optimizer.param_groups for p in g["params"]] + [self.state.pose_delta]
        if not all(bool(torch.isfinite(p.grad).all()) for p in params if p.grad is not None):
            return False
        if self.step_count % GOOD_STATE_EVERY == 0 or self._last_good is None:
            self._last_good = copy.deepcopy({"model": self.model.state_dict(), "pose_delta": self.state.pose_delta.detach(),
                                             "optimizers": [o.state_dict() for o in self._optimizers()]})
        for opt in optimizers:
            opt.step()
        if not all(bool(torch.isfinite(p).all()) for p in params):
            good = self._last_good
            self.model.load_state_dict(good["model"])
            with torch.no_grad():
                self.state.pose_delta.copy_(good["pose_delta"])
            for opt, sd in zip(self._optimizers(), good["optimizers"]):
                opt.load_state_dict(sd)
            self.restored_states += 1
            return False
        return True

    # ----- evaluation, logs, snapshots ----------------------------------------------------------
    def evaluate(self, views=None) -> tuple[list[dict], dict]:
        t0 = time.perf_counter()
        with torch.no_grad():
            rows, summary = evaluate_views(self.state, self.scene, self.background, lpips=self.lpips, views=views)
        self.elapsed += time.perf_counter() - t0  # the run's clock; not the stage's budget (see run_length)
        self.latest.update({k: v for k, v in summary.items() if v is not None})
        return rows, summary

    def validate(self) -> tuple[list[dict], dict]:
        """Seen-view validation on the held-out frames (or the training-view fit): rows and
        ``val_psnr`` / ``val_ssim`` / ``val_alpha_iou`` / ``val_kind``."""
        t0 = time.perf_counter()
        rows, summary = validate_frames(self.state, self.scene, self.val_frames, self.background)
        self.elapsed += time.perf_counter() - t0  # the run's clock; not the stage's budget
        summary = {**summary, "val_kind": self.val_kind}
        self.latest.update({k: v for k, v in summary.items() if v is not None})
        return rows, summary

    def maybe_evaluate(self, force: bool = False) -> dict | None:
        """Evaluation every ``eval_every_seconds``: the scene's evaluation views (ground truth from
        other views, where it has them) and the seen-view validation."""
        if not force and self.elapsed - self._last_eval < self.config.eval_every_seconds:
            return None
        rows, summary = self.evaluate() if self.scene.eval_views else ([], {})
        val_rows, val_summary = self.validate() if self.val_frames else ([], {})
        self._last_eval = self.elapsed
        record = {"kind": "eval", "step": self.step_count, "elapsed": round(self.elapsed, 3), "stage": self.stage,
                  **summary, **val_summary, "views": rows, "validation": val_rows}
        if self.log:
            self.log.append(record)
        return record

    def advance(self, log_every: int = 25) -> tuple[dict, dict | None]:
        """One step of a run: ``step()``, a training record every ``log_every`` steps, the periodic
        evaluation and checkpoint. Returns the step's values and the evaluation record (or None)."""
        out = self.step()
        if self.step_count % log_every == 0 or out.get("skipped"):
            self.log_step(out)
        record = self.maybe_evaluate()
        self.maybe_save()
        return out, record

    def log_step(self, out: dict) -> None:
        if self.log:
            self.log.append({"kind": "train", "step": self.step_count, "elapsed": round(self.elapsed, 3),
                             "stage": self.stage,
                             **{k: (round(v, 6) if isinstance(v, float) else v) for k, v in out.items()}})

    def avatar(self, *, frozen: bool = False) -> TrainedAvatar:
        """The avatar being trained (``frozen``: a copy that no longer changes; take it between
        steps)."""
        return TrainedAvatar(self.state.frozen() if frozen else self.state, self.scene, self.stage, self.step_count,
                             {k: v for k, v in self.latest.items() if isinstance(v, (int, float))},
                             tuple(float(c) for c in self.config.background))

    def frozen(self) -> TrainedAvatar:
        return self.avatar(frozen=True)

    def make_snapshot(self, space: str = "observation", frame_index: int = 0) -> Snapshot:
        return self.avatar().make_snapshot(space, frame_index)

    def publish(self, space: str = "observation", frame_index: int = 0) -> None:
        self.snapshots.publish(self.make_snapshot(space, frame_index))

    # ----- checkpoints --------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything to continue the run exactly: tensors and plain data only (no pickled objects)."""
        return {
            "stage": self.stage,
            "step": self.step_count,
            "elapsed": self.elapsed,
            "stage_step": self.stage_step,
            "stage_elapsed": self.stage_elapsed,
            "stage_starts": {str(k): v for k, v in self.stage_starts.items()},
            "kind_counts": dict(self.kind_counts),
            "config": self.config.to_dict(),
            "plan": self.plan.state_dict(),
            "scene_spec": self.scene_spec,
            "scene_name": self.scene.name,
            "avatar": self.state.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "pose_optimizer": self.pose_optimizer.state_dict() if self.pose_optimizer else None,
            "epoch_order": [int(i) for i in self.epoch_order],
            "rng": {"numpy": self.rng.bit_generator.state, "torch": torch.get_rng_state(),
                    "python": random.getstate()},
            "latest": plain_scalars(self.latest),
            "nonfinite_skipped": self.nonfinite_skipped,
            "restored_states": self.restored_states,
        }

    def save(self, path: str | Path | None = None) -> Path:
        if path is None:
            if self.run_dir is None:
                raise ValueError("save: no run folder and no path given")
            path = self.run_dir / CHECKPOINT_NAME
        out = save_checkpoint(self.state_dict(), path)
        self._last_ckpt = self.elapsed
        return out

    def maybe_save(self) -> Path | None:
        if self.run_dir is not None and self.elapsed - self._last_ckpt >= self.config.checkpoint_every_seconds:
            return self.save()
        return None

    def _use_garment_layer(self, layer: GarmentLayer | None) -> None:
        """Rebuild the avatar model with ``layer`` (a checkpoint's; None: without one) before the
        checkpoint is loaded into it: same body, UV map and pose encoder; the optimiser is rebuilt
        over the new parameters (its state comes from the checkpoint next)."""
        old = self.model
        model = AvatarModel(self.state.body, self.config.avatar, uv_map=old.uv_map, layer=layer).to(self.device)
        model.pose_encoder = old.pose_encoder
        self.state.replace_model(model)
        self.begin(self.plan, fresh=False)

    def load_state_dict(self, state: dict, source: str = "checkpoint") -> None:
        if state.get("scene_name") != self.scene.name:
            raise CheckpointError(f"{source}: made for scene {state.get('scene_name')!r}, not {self.scene.name!r}")
        if int(state["stage"]) != self.stage:
            raise CheckpointError(f"{source}: a Stage {state['stage']} checkpoint, loaded into a Stage {self.stage} plan")
        layer = garment_layer_of(state, source, self.state.body.num_joints)
        if not (layer is None and self.model.layer is None) and not (layer is not None and layer.same_as(self.model.layer)):
            self._use_garment_layer(layer)
        try:
            self.state.load_state_dict(state["avatar"])
            self.optimizer.load_state_dict(state["optimizer"])
        except (RuntimeError, KeyError, ValueError) as exc:
            raise CheckpointError(f"{source}: does not fit this model ({exc})") from exc
        saved = state.get("pose_optimizer")
        if self.pose_optimizer is not None and saved and _row_adam_state(saved, self.state.num_frames):
            self.pose_optimizer.load_state_dict(saved)
        # else the moments start again (a run from before RowAdam kept one Adam over all frames)
        self.step_count = int(state["step"])
        self.elapsed = float(state["elapsed"])
        self.stage_step = int(state["stage_step"])
        self.stage_elapsed = float(state["stage_elapsed"])
        self.stage_starts = {int(k): int(v) for k, v in state["stage_starts"].items()}
        self.kind_counts = {str(k): int(v) for k, v in state["kind_counts"].items()}
        self._last_ckpt = self._last_eval = self.elapsed
        self.epoch_order = [int(i) for i in state["epoch_order"]]
        self.rng.bit_generator.state = state["rng"]["numpy"]
        torch.set_rng_state(state["rng"]["torch"])
        random.setstate(_python_rng_state(state["rng"]["python"]))
        self.latest = dict(state.get("latest", {}))
        self.nonfinite_skipped = int(state.get("nonfinite_skipped", 0))
        self.restored_states = int(state.get("restored_states", 0))


def _python_rng_state(s):
    """``random.getstate()`` from a checkpoint (tuples may come back as lists)."""
    version, internal, gauss = s
    return int(version), tuple(int(v) for v in internal), gauss
