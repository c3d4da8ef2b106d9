"""Stage II (paper Sec. 3.2-3.3, Appendix A.2): the Stage I session continued with pose feature
injection and dual-space guidance of the selected unseen views.

Each step is, by the configured ratios, a *given-view* step (the Stage I loss on a training frame,
with G([S, P])) or a *dual-space* step: the avatar is rendered from an unseen view, in canonical
space (reference: the Stage I canonical front render) or in observation space at a selected input
frame (reference: that frame), cropped to the body and resized to the prior's input size, and the
prior's loss is weighted by λ_SDS(t) (Eq. 14). Unseen views come from view selection (Eq. 8-10)
run once at the start of Stage II on the Stage I seen flags, in canonical space and at each
selected reference frame.

Unseen-view normals: the paper inpaints back normals with d-BiNI and IF-Nets. Neither is
available here; the substitute is the body model's own surface normals: in dual-space steps the
normals of the Gaussians that propagation does not trust as seen are pulled towards the posed body
normals (λ_unseen_normal), the seen ones towards their current values.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..avatar.model import PosedGaussians
from ..body.pose import BodyPose
from ..camera import Camera
from ..priors.base import CameraDelta, GuidanceInput
from ..priors.propagated import build_prior
from ..train import losses as L
from ..train.checkpoint import CheckpointError
from ..train.config import Stage1Config
from ..train.render import crop_camera, render_avatar
from ..train.session import CHECKPOINT_NAME, TrainingSession, gaussians_finite
from .config import Stage2Config
from ..body.lbs import apply_normals
from ..body.uv_map import texel_neighbours
from ..raster import rasterization
from .propagation import erode, propagate_colors
from .view_selection import CandidateView, ViewSelectionConfig, azimuth_of, elevation_of, select_views

STAGE1_CHECKPOINT_NAME = "checkpoint_stage1.pt"
KINDS = ("given", "canonical", "observation")


class Stage2Error(ValueError):
    pass


@dataclass
class SpaceViews:
    """View selection in one space: canonical (``frame`` None) or observation at a reference frame."""

    frame: int | None
    reference_azimuth: float  # azimuth of the reference view around the body (degrees)
    reference_elevation: float
    target: np.ndarray  # body centre the candidates look at
    views: list[CandidateView]

    @property
    def unseen(self) -> list[CandidateView]:
        return [v for v in self.views if v.unseen]


def framed_camera(camera: Camera, points: torch.Tensor, size: int, margin: float = 0.08) -> Camera:
    """``camera`` cropped to a square around the projected ``points`` (plus ``margin`` of the box's
    side) and resized to ``size`` x ``size``: the body crop the prior sees (paper A.3)."""
    p = points.detach().double().cpu().numpy()
    xc = p @ camera.R.T + camera.t
    z = np.maximum(xc[:, 2], 1e-6)
    u = camera.K[0, 0] * xc[:, 0] / z + camera.K[0, 2]
    v = camera.K[1, 1] * xc[:, 1] / z + camera.K[1, 2]
    cx, cy = (u.min() + u.max()) / 2, (v.min() + v.max()) / 2
    side = max(u.max() - u.min(), v.max() - v.min()) * (1 + 2 * margin)
    side = max(side, 8.0)
    x0, y0 = int(math.floor(cx - side / 2)), int(math.floor(cy - side / 2))
    s = int(math.ceil(side))
    return crop_camera(camera, (x0, y0, x0 + s, y0 + s)).scaled(size, size)


def _square_crop(image: np.ndarray, mask: np.ndarray, size: int, background, margin: float = 0.08) -> torch.Tensor:
    """A frame cropped to a square around its mask (``margin`` padding), composited on the
    background and resized to ``size``: the observation-space reference."""
    ys, xs = np.nonzero(mask > 0.5)
    if len(xs) == 0:
        raise Stage2Error("a reference frame has an empty mask")
    cx, cy = (xs.min() + xs.max() + 1) / 2, (ys.min() + ys.max() + 1) / 2
    side = max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1) * (1 + 2 * margin)
    x0, y0 = int(round(cx - side / 2)), int(round(cy - side / 2))
    s = int(math.ceil(side))
    H, W = mask.shape
    bg = np.asarray(background, np.float32)
    canvas = np.empty((s, s, 3), np.float32)
    canvas[:] = bg
    sx0, sy0, sx1, sy1 = max(0, x0), max(0, y0), min(W, x0 + s), min(H, y0 + s)
    m = mask[sy0:sy1, sx0:sx1, None].astype(np.float32)
    canvas[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = image[sy0:sy1, sx0:sx1] * m + bg * (1 - m)
    t = torch.as_tensor(canvas).permute(2, 0, 1)[None]
    return F.interpolate(t, size=(size, size), mode="bilinear", antialias=True, align_corners=False)[0].permute(1, 2, 0)


class Stage2Session(TrainingSession):
    stage = 2
    marks_seen = False

    def __init__(self, scene, config: Stage1Config, stage2: Stage2Config | None = None, run_dir=None, *,
                 scene_spec: str | None = None) -> None:
        super().__init__(scene, config, run_dir, scene_spec=scene_spec)
        self.stage2 = stage2 = stage2 or Stage2Config()
        extra = {"guidance_scale": stage2.guidance_scale, "seed": config.seed} if stage2.prior == "zero123" else {}
        self.prior = build_prior(stage2.prior, stage2.prior_path, **extra)
        # Zero123 was trained on objects over white: its renders and references are composited on white
        self.guidance_background = (torch.ones(3, device=self.device) if stage2.prior == "zero123"
                                    else self.background)
        if stage2.pose_injection:
            self.model.enable_pose_injection(stage2.pose_encoder_width)
        self._build_optimizer()
        self.stage2_step = 0
        self.stage2_elapsed = 0.0
        self.stage1_step = 0
        self.kind_counts = {k: 0 for k in KINDS}
        self.spaces: list[SpaceViews] = []
        self.pseudo_colors: torch.Tensor | None = None
        self.trusted_seen: torch.Tensor | None = None
        self.canonical_reference: torch.Tensor | None = None
        self.sds_note: str | None = None
        self._references: dict[int, torch.Tensor] = {}
        self._articulations: dict[int, torch.Tensor] = {}
        self._canonical_articulation: torch.Tensor | None = None

    # ----- construction ----------------------------------------------------------------------
    def _build_optimizer(self) -> None:
        s2 = self.stage2
        groups = [{"params": self.model.decoder.parameters(), "lr": s2.lr_decoder, "name": "decoder"},
                  {"params": [self.model.features], "lr": s2.lr_features, "name": "features"}]
        if self.model.pose_encoder is not None:
            groups.append({"params": self.model.pose_encoder.parameters(), "lr": s2.lr_pose_encoder,
                           "name": "pose_encoder"})
        self.optimizer = torch.optim.Adam(groups)
        self.base_lrs = [g["lr"] for g in self.optimizer.param_groups]

    @classmethod
    def from_stage1(cls, session: TrainingSession, stage2: Stage2Config | None = None) -> "Stage2Session":
        """Take over a Stage I session: same scene, settings, run folder, weights, seen flags and
        clock. The Stage I checkpoint is kept as ``checkpoint_stage1.pt`` in the run folder."""
        if session.stage != 1:
            raise Stage2Error("Stage II starts from a Stage I session")
        if session.step_count == 0:
            raise Stage2Error("Stage II needs a trained Stage I avatar; this Stage I session has taken no step")
        s2 = cls(session.scene, session.config, stage2, None, scene_spec=session.scene_spec)
        state = session.state()
        s2.model.load_state_dict(state["model"], strict=False)
        with torch.no_grad():
            s2.pose_delta.copy_(state["pose_delta"])
        s2.seen = state["seen"].clone()
        s2.step_count = s2.stage1_step = session.step_count
        s2.elapsed = session.elapsed
        s2.latest = dict(session.latest)
        s2.lpips, s2.lpips_note = session.lpips, session.lpips_note
        s2.run_dir, s2.log = session.run_dir, session.log
        s2._last_eval, s2._last_ckpt = session.elapsed, session.elapsed
        if s2.run_dir is not None:
            session.save(s2.run_dir / STAGE1_CHECKPOINT_NAME)
        s2.prepare()
        return s2

    # ----- pose features ---------------------------------------------------------------------
    def articulation(self, frame_index: int | None) -> torch.Tensor:
        """Bone transforms of a frame's pose without its global rotation/translation (the pose
        encoder's input), or of the canonical pose for ``None``."""
        if frame_index is None:
            if self._canonical_articulation is None:
                self._canonical_articulation = self.body.canonical_transforms.float().to(self.device)
            return self._canonical_articulation
        if frame_index not in self._articulations:
            self._articulations[frame_index] = self.articulation_of_pose(self.scene.frames[frame_index].pose)
        return self._articulations[frame_index]

    def seen_flags(self) -> torch.Tensor:
        """The flags Stage II works with (eroded on the UV grid): what view selection used."""
        return self.trusted_seen if self.trusted_seen is not None else self.seen

    def articulation_of_pose(self, pose: BodyPose) -> torch.Tensor:
        return self.body.bone_transforms(BodyPose(pose.joint_rotations, np.zeros(3), np.zeros(3))).float().to(self.device)

    def _pose_terms(self, articulation: torch.Tensor):
        """G([S, P]) for a pose's articulation, and the λ_p regulariser of its pose features."""
        pf = self.model.pose_features(articulation)
        canon = self.model.canonical(pf)
        extra = {} if pf is None else {"pose_features": (L.mean_square(pf), self.stage2.lambda_pose_features)}
        return canon, extra

    def _canonical_for_step(self, frame_index: int):
        return self._pose_terms(self.articulation(frame_index))

    def canonical_at(self, frame_index: int | None = None):
        return self._pose_terms(self.articulation(frame_index))[0]

    def canonical_for_pose(self, pose: BodyPose):
        return self._pose_terms(self.articulation_of_pose(pose))[0]

    # ----- preparation: view selection, references, propagated appearance ------------------
    def _view_config(self) -> ViewSelectionConfig:
        s2 = self.stage2
        return ViewSelectionConfig(num_azimuths=s2.num_azimuths, overhead_elevation_deg=s2.overhead_elevation_deg,
                                   threshold=s2.visibility_threshold)

    def reference_frames(self, count: int = 6) -> list[int]:
        """Evenly spaced input frames used as observation-space references."""
        T = len(self.scene.frames)
        return sorted({int(round(x)) for x in np.linspace(0, T - 1, min(count, T))})

    @torch.no_grad()
    def _posed(self, frame_index: int | None) -> PosedGaussians:
        canon = self.canonical_at(frame_index)
        if frame_index is None:
            return self.model.splats(canon)
        return self.model.pose(canon, self.frame_transforms(frame_index))

    @torch.no_grad()
    def reselect_views(self) -> None:
        """View selection (Eq. 8-10) in canonical space and at each reference frame, with the
        current threshold, on the trusted (eroded) seen flags."""
        cfg = self._view_config()
        spaces = []
        for frame in [None] + self.reference_frames():
            g = self._posed(frame)
            target = g.means.mean(0).double().cpu().numpy()
            if frame is None:
                ref_az, ref_el = 0.0, 0.0  # the canonical body faces -Y: azimuth 0 is its front
            else:
                cam = self.scene.frames[frame].camera
                ref_az, ref_el = azimuth_of(cam, target), elevation_of(cam, target)
            views = select_views(g.means, g.quats, g.scales, g.opacities, self.trusted_seen, target, cfg, ref_az)
            spaces.append(SpaceViews(frame, ref_az, ref_el, target, views))
        self.spaces = spaces
        n_unseen = sum(len(s.unseen) for s in spaces)
        self.sds_note = None
        if n_unseen == 0 and self.stage2.view_selection:
            self.sds_note = (f"every candidate view is already seen (visible share > {cfg.threshold:g} in all "
                             f"{sum(len(s.views) for s in spaces)} views): Stage II skips its guidance steps")
        self.latest["unseen_views"] = n_unseen

    @property
    def selected_views(self) -> list[CandidateView]:
        return [v for s in self.spaces for v in s.views]

    @torch.no_grad()
    def prepare(self) -> None:
        """Everything Stage II fixes at its start: view selection, the canonical reference render,
        the propagated appearance (built-in prior's pseudo-target colours)."""
        t0 = time.perf_counter()
        nb = texel_neighbours(self.model.uv_map.texel_rc, self.model.uv_map.resolution)
        self.trusted_seen = torch.as_tensor(erode(self.seen.numpy(), nb, self.stage2.seen_erosion))
        self.reselect_views()
        canon = self.canonical_at(None)
        g = self.model.splats(canon)
        target = g.means.mean(0).double().cpu().numpy()
        front = Camera.orbit(0.0, 0.0, self._view_config().distance, target, width=512, height=512, fov_y_deg=30.0)
        cam = framed_camera(front, g.means, self.stage2.prior_size)
        self.canonical_reference = render_avatar(g, cam, self.guidance_background, normals=False).rgb.clamp(0, 1)
        self.pseudo_colors = propagate_colors(self.model.base_positions, self.model.parts(), self.trusted_seen,
                                              canon.colors, nb).to(self.device)
        if self.sds_note:
            print(self.sds_note, file=sys.stderr)
        self.elapsed += time.perf_counter() - t0

    def reference_image(self, frame: int | None) -> torch.Tensor:
        if frame is None:
            return self.canonical_reference
        if frame not in self._references:
            f = self.scene.frames[frame]
            self._references[frame] = _square_crop(f.image, f.mask, self.stage2.prior_size,
                                                   self.guidance_background.cpu().numpy()).to(self.device)
        return self._references[frame]

    # ----- schedule ----------------------------------------------------------------------------
    def run_length(self) -> tuple[int, int, float, float | None]:
        return self.stage2_step, self.stage2.iters, self.stage2_elapsed, self.stage2.minutes

    def _lr_decay(self) -> tuple[tuple[float, ...], float]:
        return tuple(self.stage2.lr_milestones), self.stage2.lr_gamma

    def sds_weight(self) -> float:
        return self.stage2.sds_weight(self.stage2_step)

    def _next_kind(self) -> str:
        s2 = self.stage2
        spaces = []
        if s2.canonical_sds:
            spaces.append("canonical")
        if s2.observation_sds:
            spaces.append("observation")
        if not spaces or self.sds_note or self.rng.random() < s2.given_view_ratio:
            return "given"
        if len(spaces) == 1:
            return spaces[0]
        return "canonical" if self.rng.random() < s2.canonical_ratio else "observation"

    # ----- one step ----------------------------------------------------------------------------
    def step(self) -> dict:
        t0 = time.perf_counter()
        kind = self._next_kind()
        self._apply_schedule()
        if kind == "given":
            out = super().step()
        else:
            out = self._guidance_step(kind)
        self.kind_counts[kind] += 1
        self.stage2_step += 1
        self.stage2_elapsed += time.perf_counter() - t0
        out.update({"kind": kind, "sds_weight": self.sds_weight(), "stage2_step": self.stage2_step})
        self.latest.update({"sds_weight": out["sds_weight"], "stage2_step": self.stage2_step})
        return out

    def _pick_view(self, space: str) -> tuple[SpaceViews, CandidateView]:
        pool = [s for s in self.spaces if (s.frame is None) == (space == "canonical")]
        sv = pool[int(self.rng.integers(len(pool)))]
        views = sv.unseen if self.stage2.view_selection else sv.views
        if not views:  # this frame has no unseen view: any space of the same kind that has one
            with_unseen = [s for s in pool if s.unseen]
            if not with_unseen:
                return sv, sv.views[int(self.rng.integers(len(sv.views)))]
            sv = with_unseen[int(self.rng.integers(len(with_unseen)))]
            views = sv.unseen
        return sv, views[int(self.rng.integers(len(views)))]

    def _guidance_step(self, space: str) -> dict:
        t0 = time.perf_counter()
        s2 = self.stage2
        sv, view = self._pick_view(space)
        frame = sv.frame
        canon, extra = self._pose_terms(self.articulation(frame))
        if frame is None:
            posed = self.model.splats(canon)
            body_normals = self.model.base_normals
        else:
            M = self.model.lbs_matrices(self.frame_transforms(frame))
            posed = self.model.pose_with(canon, M)
            body_normals = apply_normals(M, self.model.base_normals)
        if not gaussians_finite(posed):
            return self._skipped_step(-1 if frame is None else frame, t0, {})
        camera = framed_camera(view.camera, posed.means, s2.prior_size)
        r = render_avatar(posed, camera, self.guidance_background, normals=s2.unseen_normals)
        render = r.rgb
        clip = s2.sds_grad_clip
        if render.requires_grad and clip > 0:
            render.register_hook(lambda g: g * (clip / g.norm().clamp_min(clip)))
        trusted = self.trusted_seen.to(self.device)[:, None]

        targets: list[torch.Tensor] = []

        def detached_targets() -> torch.Tensor:
            """One render without gradients, with the avatar's current geometry, of the propagated
            colours (channels 0-2: the built-in prior's pseudo-target) and the unseen-normal targets
            in camera space (channels 3-5)."""
            if not targets:
                with torch.no_grad():
                    R = torch.as_tensor(camera.R, dtype=posed.normals.dtype, device=self.device)
                    n_target = torch.where(trusted, posed.normals, body_normals) @ R.T
                    bg = torch.cat([self.guidance_background, torch.zeros(3, device=self.device)])
                    targets.append(rasterization(posed.means.detach(), posed.quats, posed.scales.detach(),
                                                 posed.opacities, torch.cat([self.pseudo_colors, n_target], 1),
                                                 camera, background=bg).image)
            return targets[0]

        def pseudo_target() -> torch.Tensor:
            return detached_targets()[..., :3]

        delta = CameraDelta(polar=-math.radians(view.elevation_deg - sv.reference_elevation),
                            azimuth=math.radians(view.azimuth_deg), radius=0.0,
                            reference_polar=math.radians(90.0 - sv.reference_elevation))
        guidance = self.prior.loss(GuidanceInput(render.clamp(0, 1), self.reference_image(frame), delta,
                                                 progress=self.progress, alpha=r.alpha, space=space,
                                                 pseudo_target=pseudo_target))
        w = self.sds_weight()
        terms = {"sds": guidance.loss}
        weights = {"sds": w}
        if s2.unseen_normals and r.normal is not None:
            terms["unseen_normal"] = L.mse(r.normal, detached_targets()[..., 3:])
            weights["unseen_normal"] = s2.lambda_unseen_normal * (w / s2.lambda_sds if s2.lambda_sds > 0 else 0.0)
        for k, (term, wt) in extra.items():
            terms[k], weights[k] = term, wt
        loss = sum(weights[k] * v for k, v in terms.items())
        if not self._guarded_update(loss, [self.optimizer]):
            return self._skipped_step(-1 if frame is None else frame, t0, terms)
        self.step_count += 1
        self.elapsed += time.perf_counter() - t0
        out = {"loss": float(loss.detach()), **{k: float(v.detach()) for k, v in terms.items()},
               "frame": -1 if frame is None else frame, "view_azimuth": view.azimuth_deg,
               "view_elevation": view.elevation_deg, **guidance.info}
        self.latest.update({f"{space}_sds": float(guidance.loss.detach())})
        return out

    # ----- checkpoints ------------------------------------------------------------------------
    def state(self) -> dict:
        st = super().state()
        st["stage2"] = {
            "config": self.stage2.to_dict(),
            "step": self.stage2_step,
            "elapsed": self.stage2_elapsed,
            "stage1_step": self.stage1_step,
            "kind_counts": dict(self.kind_counts),
            "pseudo_colors": self.pseudo_colors.cpu() if self.pseudo_colors is not None else None,
            "trusted_seen": self.trusted_seen.clone() if self.trusted_seen is not None else None,
            "canonical_reference": self.canonical_reference.cpu() if self.canonical_reference is not None else None,
            "spaces": [{"frame": s.frame, "reference_azimuth": s.reference_azimuth,
                        "reference_elevation": s.reference_elevation, "target": s.target.tolist(),
                        "views": [(v.azimuth_deg, v.elevation_deg, v.visibility, v.unseen) for v in s.views]}
                       for s in self.spaces],
            "sds_note": self.sds_note,
        }
        return st

    def load_state(self, state: dict, source: str = "checkpoint") -> None:
        super().load_state(state, source)
        self.base_lrs = [self.stage2.lr_decoder, self.stage2.lr_features] + (
            [self.stage2.lr_pose_encoder] if self.model.pose_encoder is not None else [])
        st2 = state.get("stage2")
        if not st2:
            raise CheckpointError(f"{source}: not a Stage II checkpoint")
        self.stage2_step = int(st2["step"])
        self.stage2_elapsed = float(st2["elapsed"])
        self.stage1_step = int(st2["stage1_step"])
        self.kind_counts = dict(st2["kind_counts"])
        self.pseudo_colors = st2["pseudo_colors"].to(self.device)
        self.trusted_seen = st2["trusted_seen"].clone()
        self.canonical_reference = st2["canonical_reference"].to(self.device)
        self.sds_note = st2.get("sds_note")
        cfg = self._view_config()
        from .view_selection import candidate_cameras

        self.spaces = []
        for s in st2["spaces"]:
            target = np.asarray(s["target"])
            cams = candidate_cameras(target, cfg, s["reference_azimuth"])
            views = [CandidateView(cam, az, el, vis, unseen)
                     for (cam, _, _), (az, el, vis, unseen) in zip(cams, s["views"])]
            self.spaces.append(SpaceViews(s["frame"], s["reference_azimuth"], s["reference_elevation"], target, views))

    @classmethod
    def from_state(cls, scene, run_dir, state: dict, config: Stage1Config | None = None,
                   stage2: Stage2Config | dict | None = None) -> "Stage2Session":
        """``stage2``: the Stage II settings, or a dict of settings that replace the checkpoint's."""
        if state.get("stage", 1) != 2:
            raise CheckpointError(f"{Path(run_dir) / CHECKPOINT_NAME}: a Stage I checkpoint, not Stage II")
        cfg = config or Stage1Config.from_dict(state["config"])
        if not isinstance(stage2, Stage2Config):
            stage2 = Stage2Config.from_dict({**state["stage2"]["config"], **(stage2 or {})})
        session = cls(scene, cfg, stage2, run_dir, scene_spec=state.get("scene_spec"))
        session.load_state(state, str(Path(run_dir) / CHECKPOINT_NAME))
        return session


def start_stage2(session: TrainingSession, stage2: Stage2Config, *, allow_incomplete: bool = False) -> Stage2Session:
    """Checks that ``session`` is a finished Stage I run and starts Stage II on it."""
    if session.stage == 2:
        return session
    if not session.done and not allow_incomplete:
        cfg = session.config
        raise Stage2Error(f"Stage I is incomplete (step {session.step_count} of {cfg.iters}"
                          + (f", {session.elapsed / 60:.1f} of {cfg.minutes:g} min" if cfg.minutes else "")
                          + "): finish it with `train --stage 1`, or pass --allow-incomplete")
    return Stage2Session.from_stage1(session, stage2)

