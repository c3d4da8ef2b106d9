"""Stage II as a plan (paper Sec. 3.2-3.3, Appendix A.2) on the avatar Stage I trained.

Each step is, by the configured ratios, a given-view step (the Stage I loss on a video frame, with
G([S, P])) or a dual-space guidance step (``guidance.GuidanceStep``) in canonical or observation
space. Unseen views come from view selection (Eq. 8-10), run once when the plan starts on the
trusted (eroded) seen flags, in canonical space and at each reference frame; the references and
the propagated appearance (the built-in prior's pseudo-target colours) are fixed then too.

A garment layer (``AvatarConfig.garment_layer``) takes part in all of it: its Gaussians are in the
visibility maps (with their opacities), their seen flags are eroded over the layer's own grid
(``AvatarModel.neighbours``) and the propagated appearance fills them as one more part
("garment": the band of seen layer Gaussians round the tube at the same height, the mirrored
colour through the part's coronal plane -- the same row at theta -> pi - theta).

``start_stage2`` switches a trainer that finished Stage I to this plan; ``restore_stage2`` builds
the plan a Stage II checkpoint is loaded into.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..camera import Camera
from ..appearance.propagation import erode_by_part
from ..appearance.pseudo_appearance import pseudo_appearance
from ..appearance.wrap_fill import grazing_rule_for
from ..priors.propagated import build_prior
from ..train.checkpoint import STAGE1_CHECKPOINT_NAME
from ..train.plan import StagePlan
from ..train.render import render_avatar
from ..train.steps import GivenViewStep
from .config import Stage2Config
from .guidance import GuidanceStep, Stage2Error, framed_camera, square_crop
from .view_selection import (CandidateView, ViewSelectionConfig, azimuth_of, candidate_cameras, elevation_of,
                             select_views)

if TYPE_CHECKING:
    from ..avatar.state import AvatarState
    from ..train.trainer import Trainer

KINDS = ("given", "canonical", "observation")


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


class Stage2Plan(StagePlan):
    stage = 2

    def __init__(self, trainer: Trainer, settings: Stage2Config) -> None:
        self.settings = s2 = settings
        # Zero123 on the training's device (left to itself it takes CUDA whenever there is one)
        extra = ({"guidance_scale": s2.guidance_scale, "seed": trainer.config.seed, "device": trainer.device}
                 if s2.prior == "zero123" else {})
        self.prior = build_prior(s2.prior, s2.prior_path, **extra)
        # Zero123 was trained on objects over white: its renders and references are composited on white
        self.guidance_background = (torch.ones(3, device=trainer.device) if s2.prior == "zero123"
                                    else trainer.background)
        self.steps = {"given": GivenViewStep(trainer.config, marks_seen=False,
                                             lambda_pose_features=s2.lambda_pose_features,
                                             layer_colour_outside=s2.layer_colour_outside),
                      "canonical": GuidanceStep("canonical", self, self.prior),
                      "observation": GuidanceStep("observation", self, self.prior)}
        self.scene = trainer.scene
        self.grazing_rule = grazing_rule_for(trainer.config)
        self.training_frames = list(trainer.data.frames)
        self.spaces: list[SpaceViews] = []
        self.pseudo_colors: torch.Tensor | None = None
        self.canonical_reference: torch.Tensor | None = None
        self.sds_note: str | None = None
        self._references: dict[int, torch.Tensor] = {}
        self.visibility_key = ""  # the painted visibility (edits) the views and pseudo-colours were made for

    # ----- the plan's interface -------------------------------------------------------------
    def param_groups(self, state: AvatarState) -> list[dict]:
        s2, model = self.settings, state.model
        groups = [{"params": model.decoder.parameters(), "lr": s2.lr_decoder, "name": "decoder"},
                  {"params": [model.features], "lr": s2.lr_features, "name": "features"},
                  *model.layer_param_groups(s2.lr_features, s2.lr_decoder)]  # [] without a garment layer
        if model.pose_encoder is not None:
            groups.append({"params": model.pose_encoder.parameters(), "lr": s2.lr_pose_encoder, "name": "pose_encoder"})
        return groups

    def next_kind(self, rng: np.random.Generator) -> str:
        s2 = self.settings
        spaces = [k for k, on in (("canonical", s2.canonical_sds), ("observation", s2.observation_sds)) if on]
        if not spaces or self.sds_note or rng.random() < s2.given_view_ratio:
            return "given"
        if len(spaces) == 1:
            return spaces[0]
        return "canonical" if rng.random() < s2.canonical_ratio else "observation"

    def sds_weight(self, stage_step: int) -> float:
        return self.settings.sds_weight(stage_step)

    def status(self, stage_step: int) -> dict:
        return {"sds_weight": self.sds_weight(stage_step), "unseen_views": self.num_unseen}

    def describe(self) -> str:
        s2 = self.settings
        return (f"prior {self.prior.describe()}; {self.num_unseen} unseen of {len(self.selected_views)} candidate "
                f"views (threshold {s2.visibility_threshold:g}); " + super().describe())

    def update_settings(self, settings: Stage2Config, state: AvatarState) -> None:
        """New settings for the running plan (the studio's sliders); view selection is redone when
        the visibility threshold changed."""
        old = self.settings.visibility_threshold
        self.settings = settings
        for step in self.steps.values():
            if isinstance(step, GivenViewStep):
                step.lambda_pose_features = settings.lambda_pose_features
        if settings.visibility_threshold != old:
            self.reselect_views(state)

    # ----- view selection, references, propagated appearance --------------------------------
    def view_config(self) -> ViewSelectionConfig:
        s2 = self.settings
        return ViewSelectionConfig(num_azimuths=s2.num_azimuths, overhead_elevation_deg=s2.overhead_elevation_deg,
                                   threshold=s2.visibility_threshold)

    def reference_frames(self, count: int = 6) -> list[int]:
        """Evenly spaced training frames (held-out validation frames left out) used as
        observation-space references."""
        frames = self.training_frames
        T = len(frames)
        return sorted({frames[int(round(x))] for x in np.linspace(0, T - 1, min(count, T))})

    @property
    def selected_views(self) -> list[CandidateView]:
        return [v for s in self.spaces for v in s.views]

    @property
    def num_unseen(self) -> int:
        return sum(len(s.unseen) for s in self.spaces)

    @torch.no_grad()
    def reselect_views(self, state: AvatarState) -> None:
        """View selection (Eq. 8-10) in canonical space and at each reference frame, with the
        current threshold, on the trusted (eroded) seen flags."""
        cfg = self.view_config()
        spaces = []
        for frame in [None] + self.reference_frames():
            g = state.splats("canonical") if frame is None else state.posed(frame)
            target = g.means.mean(0).double().cpu().numpy()
            if frame is None:
                ref_az, ref_el = 0.0, 0.0  # the canonical body faces -Y: azimuth 0 is its front
            else:
                cam = self.scene.frames[frame].camera
                ref_az, ref_el = azimuth_of(cam, target), elevation_of(cam, target)
            views = select_views(g.means, g.quats, g.scales, g.opacities, state.trusted_seen, target, cfg, ref_az)
            spaces.append(SpaceViews(frame, ref_az, ref_el, target, views))
        self.spaces = spaces
        self.sds_note = None
        if self.num_unseen == 0 and self.settings.view_selection:
            self.sds_note = (f"every candidate view is already seen (visible share > {cfg.threshold:g} in all "
                             f"{len(self.selected_views)} views): Stage II skips its guidance steps")

    @torch.no_grad()
    def prepare(self, state: AvatarState) -> None:
        """Everything Stage II fixes at its start: the trusted seen flags, view selection, the
        canonical reference render, the propagated appearance."""
        model = state.model
        nb = model.neighbours()  # body texels on the UV atlas, a garment layer on its own grid
        state.trusted_seen = torch.as_tensor(erode_by_part(state.seen.numpy(), nb, model.parts(),
                                                           self.settings.seen_erosion))
        self.reselect_views(state)
        canon = state.canonical(None)
        g = model.splats(canon)
        target = g.means.mean(0).double().cpu().numpy()
        front = Camera.orbit(0.0, 0.0, self.view_config().distance, target, width=512, height=512, fov_y_deg=30.0)
        cam = framed_camera(front, g.means, self.settings.prior_size)
        self.canonical_reference = render_avatar(g, cam, self.guidance_background, normals=False).rgb.clamp(0, 1)
        self.pseudo_colors = self.propagated_colors(model, state, canon.colors, nb).to(state.device)
        self.visibility_key = state.edits.visibility_key()
        if self.sds_note:
            print(self.sds_note, file=sys.stderr)

    @torch.no_grad()
    def refresh_visibility(self, state: AvatarState) -> None:
        """After the painted visibility changed (edits: seen / unseen / redo): view selection and
        the propagated appearance redone on the painted flags (``state.trusted_seen``)."""
        model = state.model
        self.reselect_views(state)
        nb = model.neighbours()  # body texels on the UV atlas, a garment layer on its own grid
        self.pseudo_colors = self.propagated_colors(model, state, state.canonical(None).colors, nb).to(state.device)
        self.visibility_key = state.edits.visibility_key()

    def sync_visibility(self, state: AvatarState) -> bool:
        """``refresh_visibility`` when the painted visibility is not the one the plan was made for
        (edits made elsewhere, e.g. the headless ``edit`` command). True when it refreshed."""
        if state.edits.visibility_key() == self.visibility_key:
            return False
        self.refresh_visibility(state)
        return True

    def propagated_colors(self, model, state: AvatarState, colors: torch.Tensor, neighbours: np.ndarray) -> torch.Tensor:
        """The built-in prior's pseudo-appearance (``appearance.pseudo_appearance``): the unseen
        Gaussians' colours carried from the sources of Stage I's fill (``propagation``: ``wrap``, the
        wrap-around fill of wrap_fill.py, or ``diffusion``, the earlier screened harmonic fill with
        mirrored colours)."""
        return pseudo_appearance(state, state.trusted_seen, colors, neighbours, self.settings.seen_erosion,
                                 grazing_rule=self.grazing_rule, propagation=self.settings.propagation)

    def reference_image(self, trainer: Trainer, frame: int | None) -> torch.Tensor:
        if frame is None:
            return self.canonical_reference
        if frame not in self._references:
            f = self.scene.frames[frame]
            self._references[frame] = square_crop(f.image, f.mask, self.settings.prior_size,
                                                  self.guidance_background.cpu().numpy()).to(trainer.device)
        return self._references[frame]

    def pick_view(self, space: str, rng: np.random.Generator) -> tuple[SpaceViews, CandidateView]:
        pool = [s for s in self.spaces if (s.frame is None) == (space == "canonical")]
        sv = pool[int(rng.integers(len(pool)))]
        views = sv.unseen if self.settings.view_selection else sv.views
        if not views:  # this frame has no unseen view: any space of the same kind that has one
            with_unseen = [s for s in pool if s.unseen]
            if not with_unseen:
                return sv, sv.views[int(rng.integers(len(sv.views)))]
            sv = with_unseen[int(rng.integers(len(with_unseen)))]
            views = sv.unseen
        return sv, views[int(rng.integers(len(views)))]

    # ----- checkpoints ----------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {
            "settings": self.settings.to_dict(),
            "pseudo_colors": self.pseudo_colors.cpu() if self.pseudo_colors is not None else None,
            "canonical_reference": self.canonical_reference.cpu() if self.canonical_reference is not None else None,
            "spaces": [{"frame": s.frame, "reference_azimuth": s.reference_azimuth,
                        "reference_elevation": s.reference_elevation, "target": [float(x) for x in s.target],
                        "views": [(float(v.azimuth_deg), float(v.elevation_deg), float(v.visibility), bool(v.unseen))
                                  for v in s.views]}
                       for s in self.spaces],
            "sds_note": self.sds_note,
            "visibility_key": self.visibility_key,
        }

    def load_state_dict(self, d: dict, device) -> None:
        self.pseudo_colors = d["pseudo_colors"].to(device)
        self.canonical_reference = d["canonical_reference"].to(device)
        self.sds_note = d.get("sds_note")
        self.visibility_key = str(d.get("visibility_key", ""))
        cfg = self.view_config()
        self.spaces = []
        for s in d["spaces"]:
            target = np.asarray(s["target"], np.float64)
            cams = candidate_cameras(target, cfg, s["reference_azimuth"])
            views = [CandidateView(cam, az, el, vis, unseen)
                     for (cam, _, _), (az, el, vis, unseen) in zip(cams, s["views"])]
            frame = None if s["frame"] is None else int(s["frame"])
            self.spaces.append(SpaceViews(frame, s["reference_azimuth"], s["reference_elevation"], target, views))


def _with_pose_injection(trainer: Trainer, settings: Stage2Config) -> None:
    """The pose encoder E (Eq. 12-13), seeded from the run's seed so a Stage II started right after
    Stage I and one started from a reloaded Stage I begin alike."""
    if settings.pose_injection and trainer.state.model.pose_encoder is None:
        torch.manual_seed(trainer.config.seed)
        trainer.state.model.enable_pose_injection(settings.pose_encoder_width)


def start_stage2(trainer: Trainer, settings: Stage2Config, *, allow_incomplete: bool = False) -> Stage2Plan:
    """Switch a trainer that finished Stage I to Stage II (its Stage I checkpoint is kept as
    ``checkpoint_stage1.pt`` in the run folder). Returns the running plan."""
    if trainer.stage == 2:
        return trainer.plan
    if trainer.step_count == 0:
        raise Stage2Error("Stage II needs a trained Stage I avatar; this Stage I run has taken no step")
    if not trainer.done and not allow_incomplete:
        s = trainer.plan.settings
        raise Stage2Error(f"Stage I is incomplete (step {trainer.stage_step} of {s.iters}"
                          + (f", {trainer.stage_elapsed / 60:.1f} of {s.minutes:g} min" if s.minutes else "")
                          + "): finish it with `train --stage 1`, or pass --allow-incomplete")
    if trainer.run_dir is not None:
        trainer.save(trainer.run_dir / STAGE1_CHECKPOINT_NAME)
    t0 = time.perf_counter()
    plan = Stage2Plan(trainer, settings)
    _with_pose_injection(trainer, settings)
    trainer.begin(plan)
    plan.prepare(trainer.state)
    dt = time.perf_counter() - t0
    trainer.elapsed += dt
    trainer.stage_elapsed += dt
    trainer.latest["unseen_views"] = plan.num_unseen
    return plan


def restore_stage2(trainer: Trainer, plan_state: dict, overrides: dict | None = None) -> Stage2Plan:
    """The Stage II plan of a checkpoint's ``plan`` entry (``overrides``: settings that replace
    the checkpoint's), ready for the trainer to load the rest of the checkpoint into."""
    settings = Stage2Config.from_dict({**plan_state["settings"], **(overrides or {})})
    _with_pose_injection(trainer, settings)
    plan = Stage2Plan(trainer, settings)
    plan.load_state_dict(plan_state, trainer.device)
    return plan
