"""TrainingSession: owns the scene, the avatar, the optimiser and the run folder; runs ``step()``;
publishes Snapshots for the renderer; writes checkpoints atomically and resumes from them."""

from __future__ import annotations

import json
import math
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ..avatar.model import AvatarModel
from ..body.pose import BodyPose
from ..data.scene import Scene
from ..metrics import load_lpips_or_none
from ..atomic import atomic_output
from ..snapshot import Snapshot, SnapshotBox
from . import losses as L
from .checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from .config import Stage1Config
from .evaluate import evaluate_views
from .metrics_log import MetricsLog
from .render import crop_camera, mask_box, render_avatar
from .schedule import step_decay

CHECKPOINT_NAME = "checkpoint.pt"
GOOD_STATE_EVERY = 100  # steps between in-memory copies of the last good state


def gaussians_finite(g) -> bool:
    """Whether posed Gaussians are all finite (a bad decoder output or pose must not reach the
    rasterizer, whose input check would stop the run)."""
    return all(bool(torch.isfinite(t).all()) for t in (g.means, g.scales, g.colors, g.normals))


class TrainingSession:
    stage = 1
    marks_seen = True  # Stage I marks first-hit Gaussians as seen (Eq. 7); Stage II keeps the flags

    def __init__(self, scene: Scene, config: Stage1Config | None = None, run_dir: str | Path | None = None,
                 *, scene_spec: str | None = None) -> None:
        self.scene = scene
        self.config = config = config or Stage1Config()
        self.scene_spec = scene_spec or scene.name
        self.device = torch.device(config.device)
        if config.threads:
            torch.set_num_threads(config.threads)
        torch.manual_seed(config.seed)
        self.rng = np.random.default_rng(config.seed)
        self.body = scene.body_model()
        self.model = AvatarModel(self.body, config.avatar).to(self.device)
        self.background = torch.tensor(config.background, dtype=torch.float32, device=self.device)
        self.optimizer = torch.optim.Adam([
            {"params": self.model.decoder.parameters(), "lr": config.lr_decoder, "name": "decoder"},
            {"params": [self.model.features], "lr": config.lr_features, "name": "features"},
        ])
        self.base_lrs = [g["lr"] for g in self.optimizer.param_groups]
        J = self.body.num_joints
        T = len(scene.frames)
        self.pose_delta = torch.nn.Parameter(torch.zeros(T, J + 2, 3, dtype=torch.float64))  # joints, orient, transl
        self.pose_optimizer = torch.optim.Adam([self.pose_delta], lr=config.lr_pose) if config.pose_refinement else None
        self.step_count = 0
        self.elapsed = 0.0  # seconds spent in steps and evaluations, accumulated over resumes
        self.epoch_order: list[int] = []
        self.seen = torch.zeros(self.model.num_gaussians, dtype=torch.bool)
        self.lpips, reason = load_lpips_or_none({"net": config.lpips_net, "backbone_path": config.lpips_backbone,
                                                 "lin_path": config.lpips_lin} if config.lpips_backbone else None)
        self.lpips_note = None if self.lpips is not None else f"LPIPS left out: {reason or 'no weights given'}"
        if self.lpips is not None:
            self.lpips = self.lpips.to(self.device).eval()
            for p in self.lpips.parameters():
                p.requires_grad_(False)
        self.use_normals = scene.has_normals
        self._targets = [self._prepare_frame(i) for i in range(T)]
        self._transforms: dict[int, torch.Tensor] = {}
        self.snapshots = SnapshotBox()
        self.latest: dict = {}
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.log = MetricsLog(self.run_dir / "metrics.jsonl") if self.run_dir else None
        self._last_eval = -math.inf
        self._last_ckpt = 0.0
        self.nonfinite_skipped = 0  # steps skipped for a non-finite loss or gradient
        self.restored_states = 0  # times a non-finite parameter brought back the last good state
        self._last_good: dict | None = None

    # ----- data ---------------------------------------------------------------------------
    def _prepare_frame(self, i: int) -> dict:
        f = self.scene.frames[i]
        if f.mask.max() <= 0:
            raise ValueError(f"scene {self.scene.name}: frame {i} has an empty mask (no person to learn from)")
        box = mask_box(f.mask, self.config.crop_margin)
        x0, y0, x1, y1 = box
        as_t = lambda a: torch.as_tensor(np.ascontiguousarray(a[y0:y1, x0:x1]), dtype=torch.float32, device=self.device)
        mask = as_t(f.mask)
        image = as_t(f.image) + (1 - mask[..., None]) * self.background
        normal = as_t(f.normal) if f.normal is not None else None
        return {"camera": crop_camera(f.camera, box), "image": image, "mask": mask, "normal": normal, "box": box}

    def frame_transforms(self, i: int, refined: bool = True) -> torch.Tensor:
        if refined and self.config.pose_refinement:
            return self._refined_transforms(i)
        if i not in self._transforms:
            self._transforms[i] = self.body.bone_transforms(self.scene.frames[i].pose).float().to(self.device)
        return self._transforms[i]

    def _refined_transforms(self, i: int) -> torch.Tensor:
        p = self.scene.frames[i].pose
        d = self.pose_delta[i]
        f64 = dict(dtype=torch.float64)
        T = self.body.bone_transforms_t(torch.as_tensor(p.joint_rotations, **f64) + d[:-2],
                                        torch.as_tensor(p.global_orient, **f64) + d[-2],
                                        torch.as_tensor(p.transl, **f64) + d[-1])
        return T.float().to(self.device)

    def refined_pose(self, i: int) -> BodyPose:
        p = self.scene.frames[i].pose
        d = self.pose_delta[i].detach().numpy()
        return BodyPose(p.joint_rotations + d[:-2], p.global_orient + d[-2], p.transl + d[-1])

    def _next_frame(self) -> int:
        if not self.epoch_order:
            self.epoch_order = list(self.rng.permutation(len(self.scene.frames)))
        return int(self.epoch_order.pop())

    # ----- schedule -----------------------------------------------------------------------
    def run_length(self) -> tuple[int, int, float, float | None]:
        """(steps taken, steps planned, seconds spent, minutes planned) of the running stage."""
        return self.step_count, self.config.iters, self.elapsed, self.config.minutes

    @property
    def progress(self) -> float:
        """Fraction of the running stage done: whichever of steps or minutes ends first."""
        steps, iters, seconds, minutes = self.run_length()
        p = steps / iters
        if minutes:
            p = max(p, seconds / (60.0 * minutes))
        return min(p, 1.0)

    @property
    def done(self) -> bool:
        return self.progress >= 1.0

    def _lr_decay(self) -> tuple[tuple[float, ...], float]:
        """(milestones as fractions of the run, factor) of the step learning-rate decay."""
        return tuple(self.config.lr_milestones), self.config.lr_gamma

    def _apply_schedule(self) -> None:
        mult = step_decay(self.progress, *self._lr_decay())
        for g, base in zip(self.optimizer.param_groups, self.base_lrs):
            g["lr"] = base * mult

    # ----- one step -----------------------------------------------------------------------
    def step(self) -> dict:
        t0 = time.perf_counter()
        cfg = self.config
        self._apply_schedule()
        i = self._next_frame()
        tgt = self._targets[i]
        refine = self.pose_optimizer is not None and self.progress >= cfg.pose_refinement_start
        canon, extra = self._canonical_for_step(i)
        transforms = self.frame_transforms(i, refined=refine)
        posed = self.model.pose(canon, transforms)
        if not gaussians_finite(posed):
            return self._skipped_step(i, t0, {})
        r = render_avatar(posed, tgt["camera"], self.background, normals=self.use_normals, first_hit=True,
                          hit_threshold=cfg.hit_threshold)
        terms = {
            "rgb": L.mse(r.rgb, tgt["image"]),
            "ssim": L.ssim_loss(r.rgb, tgt["image"]),
            "offset": L.mean_square(canon.offsets_raw),
            "scale": L.mean_square(canon.scales),
            "features": L.mean_square(canon.features),
        }
        weights = {"rgb": cfg.lambda_rgb, "ssim": cfg.lambda_ssim, "offset": cfg.lambda_offset,
                   "scale": cfg.lambda_scale, "features": cfg.lambda_features}
        if self.use_normals and tgt["normal"] is not None:
            terms["normal"] = L.mse(r.normal, tgt["normal"])
            weights["normal"] = cfg.lambda_normal
        if self.lpips is not None:
            terms["lpips"] = self.lpips(r.rgb[None].clamp(0, 1), tgt["image"][None]).mean()
            weights["lpips"] = cfg.lambda_lpips
        for k, (term, w) in extra.items():
            terms[k], weights[k] = term, w
        loss = sum(weights[k] * v for k, v in terms.items())
        optimizers = [self.optimizer] + ([self.pose_optimizer] if refine else [])
        if not self._guarded_update(loss, optimizers):
            return self._skipped_step(i, t0, terms)
        if self.marks_seen:
            self._mark_seen(r.first_hit, posed, tgt["camera"])
        self.step_count += 1
        self.elapsed += time.perf_counter() - t0
        out = {"loss": float(loss.detach()), **{k: float(v.detach()) for k, v in terms.items()}, "frame": i,
               "psnr_train": float(-10 * torch.log10(terms["rgb"].detach().clamp_min(1e-12)))}
        self.latest.update(out)
        return out

    def _canonical_for_step(self, frame_index: int):
        """The canonical Gaussians a step on ``frame_index`` renders, and extra loss terms
        {name: (value, weight)}. Stage I: G([S, S]), nothing extra."""
        return self.model.canonical(), {}

    def canonical_at(self, frame_index: int | None = None):
        """Canonical Gaussians for a frame's pose (``None``: the canonical pose), without gradients
        needed. Stage I's do not depend on the pose."""
        return self.model.canonical()

    def seen_flags(self) -> torch.Tensor:
        """The per-Gaussian seen flags the renderer's visibility mode shows (Stage I: Eq. 7's)."""
        return self.seen

    def canonical_for_pose(self, pose: BodyPose):
        """Canonical Gaussians for any pose (novel-pose animation); Stage I's do not depend on it."""
        return self.model.canonical()

    # ----- guards against non-finite numbers -------------------------------------------------
    def _trainable(self) -> list[torch.Tensor]:
        return [p for g in self.optimizer.param_groups for p in g["params"]] + [self.pose_delta]

    def _guarded_update(self, loss: torch.Tensor, optimizers: list) -> bool:
        """Backward and step unless the loss or a gradient is non-finite; after the step, a
        non-finite parameter restores the last good state. False when the step was not taken."""
        if not torch.isfinite(loss):
            return False
        for opt in optimizers:
            opt.zero_grad(set_to_none=True)
        if self.pose_optimizer is not None:
            self.pose_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        params = self._trainable()
        if not all(bool(torch.isfinite(p.grad).all()) for p in params if p.grad is not None):
            return False
        if self.step_count % GOOD_STATE_EVERY == 0 or self._last_good is None:
            self._keep_good_state()
        for opt in optimizers:
            opt.step()
        if not all(bool(torch.isfinite(p).all()) for p in params):
            self._restore_good_state()
            return False
        return True

    def _keep_good_state(self) -> None:
        import copy

        self._last_good = copy.deepcopy({"model": self.model.state_dict(), "pose_delta": self.pose_delta.detach(),
                                         "optimizers": [o.state_dict() for o in self._optimizers()]})

    def _restore_good_state(self) -> None:
        good = self._last_good
        self.model.load_state_dict(good["model"])
        with torch.no_grad():
            self.pose_delta.copy_(good["pose_delta"])
        for opt, sd in zip(self._optimizers(), good["optimizers"]):
            opt.load_state_dict(sd)
        self.restored_states += 1

    def _optimizers(self) -> list:
        return [self.optimizer] + ([self.pose_optimizer] if self.pose_optimizer is not None else [])

    def _skipped_step(self, frame: int, t0: float, terms: dict) -> dict:
        """A step whose numbers were not finite: nothing was changed (or the last good state was
        restored); the step still counts so a run cannot loop forever on a bad frame."""
        self.nonfinite_skipped += 1
        self.step_count += 1
        self.elapsed += time.perf_counter() - t0
        bad = {k: float(v.detach()) for k, v in terms.items()}
        print(f"step {self.step_count}: non-finite loss or gradient on frame {frame} ({bad}); step skipped "
              f"({self.nonfinite_skipped} so far)", file=sys.stderr)
        out = {"skipped": True, "frame": frame, "nonfinite_skipped": self.nonfinite_skipped,
               "restored_states": self.restored_states}
        self.latest.update({"nonfinite_skipped": self.nonfinite_skipped, "restored_states": self.restored_states})
        return out

    @torch.no_grad()
    def _mark_seen(self, first_hit: torch.Tensor, posed, camera) -> None:
        """Paper Eq. 7: a Gaussian is seen when it is the first hit of a training ray -- counted only
        where it faces the camera. Without the facing test, Gaussians on the back of thin limbs whose
        footprint spills past the outline are first hits on outline pixels and would be marked seen."""
        hits = torch.unique(first_hit[first_hit >= 0])
        if len(hits) == 0:
            return
        centre = torch.as_tensor(camera.center, dtype=posed.means.dtype, device=posed.means.device)
        facing = ((posed.means[hits] - centre) * posed.normals[hits]).sum(1) < 0
        self.seen[hits[facing].cpu()] = True

    # ----- evaluation and snapshots ---------------------------------------------------------
    def evaluate(self, views=None) -> tuple[list[dict], dict]:
        t0 = time.perf_counter()
        with torch.no_grad():
            rows, summary = evaluate_views(self.model, self.canonical_at, self.scene, self.frame_transforms, self.background,
                                           lpips=self.lpips, views=views)
        self.elapsed += time.perf_counter() - t0
        self.latest.update({k: v for k, v in summary.items() if v is not None})
        return rows, summary

    def maybe_evaluate(self, force: bool = False) -> dict | None:
        if not self.scene.eval_views:
            return None
        if not force and self.elapsed - self._last_eval < self.config.eval_every_seconds:
            return None
        rows, summary = self.evaluate()
        self._last_eval = self.elapsed
        record = {"kind": "eval", "step": self.step_count, "elapsed": round(self.elapsed, 3), "stage": self.stage, **summary,
                  "views": rows}
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
            self.log.append({"kind": "train", "step": self.step_count, "elapsed": round(self.elapsed, 3), "stage": self.stage,
                             **{k: (round(v, 6) if isinstance(v, float) else v) for k, v in out.items()}})

    @torch.no_grad()
    def make_snapshot(self, space: str = "observation", frame_index: int = 0) -> Snapshot:
        if space == "canonical":
            g = self.model.splats(self.canonical_at(None))
        elif space == "observation":
            g = self.model.pose(self.canonical_at(frame_index), self.frame_transforms(frame_index))
        else:
            raise ValueError(f"snapshot space must be 'observation' or 'canonical', found {space!r}")
        return Snapshot.from_gaussians(g, self.seen_flags(), space=space, frame_index=frame_index, stage=self.stage,
                                       step=self.step_count,
                                       metrics={k: v for k, v in self.latest.items() if isinstance(v, (int, float))})

    def publish(self, space: str = "observation", frame_index: int = 0) -> None:
        self.snapshots.publish(self.make_snapshot(space, frame_index))

    # ----- checkpoints --------------------------------------------------------------------
    def state(self) -> dict:
        return {
            "stage": self.stage,
            "step": self.step_count,
            "elapsed": self.elapsed,
            "config": self.config.to_dict(),
            "scene_spec": self.scene_spec,
            "scene_name": self.scene.name,
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "pose_delta": self.pose_delta.detach().clone(),
            "pose_optimizer": self.pose_optimizer.state_dict() if self.pose_optimizer else None,
            "seen": self.seen.clone(),
            "epoch_order": list(self.epoch_order),
            "rng": {"numpy": self.rng.bit_generator.state, "torch": torch.get_rng_state(), "python": random.getstate()},
            "latest": self.latest,
            "nonfinite_skipped": self.nonfinite_skipped,
            "restored_states": self.restored_states,
        }

    def save(self, path: str | Path | None = None) -> Path:
        if path is None:
            if self.run_dir is None:
                raise ValueError("save: no run folder and no path given")
            path = self.run_dir / CHECKPOINT_NAME
        out = save_checkpoint(self.state(), path)
        self._last_ckpt = self.elapsed
        return out

    def maybe_save(self) -> Path | None:
        if self.run_dir is not None and self.elapsed - self._last_ckpt >= self.config.checkpoint_every_seconds:
            return self.save()
        return None

    def load_state(self, state: dict, source: str = "checkpoint") -> None:
        if state.get("scene_name") != self.scene.name:
            raise CheckpointError(f"{source}: made for scene {state.get('scene_name')!r}, not {self.scene.name!r}")
        try:
            self.model.load_state_dict(state["model"])
            self.optimizer.load_state_dict(state["optimizer"])
        except (RuntimeError, KeyError, ValueError) as exc:
            raise CheckpointError(f"{source}: does not fit this model ({exc})") from exc
        self.base_lrs = [self.config.lr_decoder, self.config.lr_features]
        with torch.no_grad():
            self.pose_delta.copy_(state["pose_delta"])
        if self.pose_optimizer is not None and state.get("pose_optimizer"):
            self.pose_optimizer.load_state_dict(state["pose_optimizer"])
        self.step_count = int(state["step"])
        self.elapsed = float(state["elapsed"])
        self._last_ckpt = self.elapsed
        self._last_eval = self.elapsed
        self.seen = state["seen"].clone()
        self.epoch_order = [int(i) for i in state["epoch_order"]]
        self.rng.bit_generator.state = state["rng"]["numpy"]
        torch.set_rng_state(state["rng"]["torch"])
        random.setstate(state["rng"]["python"])
        self.latest = dict(state.get("latest", {}))
        self.nonfinite_skipped = int(state.get("nonfinite_skipped", 0))
        self.restored_states = int(state.get("restored_states", 0))

    @classmethod
    def resume(cls, scene: Scene, run_dir: str | Path, config: Stage1Config | None = None) -> "TrainingSession":
        """The session of ``run_dir``'s checkpoint (read once): Stage I, or Stage II when the run is
        in Stage II."""
        run_dir = Path(run_dir)
        state = load_checkpoint(run_dir / CHECKPOINT_NAME)
        if state.get("stage", 1) == 2 and cls.stage == 1:
            from ..stage2.session import Stage2Session

            cls = Stage2Session
        return cls.from_state(scene, run_dir, state, config)

    @classmethod
    def from_state(cls, scene: Scene, run_dir: str | Path, state: dict,
                   config: Stage1Config | None = None) -> "TrainingSession":
        """A session on ``run_dir`` restored from its loaded checkpoint ``state``; ``config``
        replaces the checkpoint's settings when given."""
        cfg = config or Stage1Config.from_dict(state["config"])
        session = cls(scene, cfg, run_dir, scene_spec=state.get("scene_spec"))
        session.load_state(state, str(Path(run_dir) / CHECKPOINT_NAME))
        return session


def write_run_info(run_dir: Path, scene_spec: str, config: Stage1Config) -> None:
    update_run_info(run_dir, {"scene": scene_spec, "stage": 1, "config": config.to_dict(),
                              "python": sys.version.split()[0], "torch": torch.__version__})


def update_run_info(run_dir: Path, fields: dict) -> None:
    """Sets ``fields`` in the run folder's ``run.json`` (written atomically)."""
    path = Path(run_dir) / "run.json"
    info = json.loads(path.read_text()) if path.exists() else {}
    info.update(fields)
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(info, indent=1))
