"""A stage is a plan: what it optimises and at which learning rates, the mix of step kinds, and
its length and learning-rate decay (``StageSettings``). The trainer runs whatever plan it is given
on the same avatar state; Stage II is a second plan (``reconstruct.stage2.plan``), not a second
kind of trainer."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from .config import Stage1Config, StageSettings
from ..appearance.wrap_fill import grazing_rule_for
from ..avatar.layer_depth import match_layer_depth
from .hem_trim import trim_layer_hem
from .hidden_by_limbs import hidden_by_limbs
from .seen_recount import keep_seen_on_person, person_coverage, unsee_untrained
from .steps import GivenViewStep, TrainingStep
from .unseen_fill import (cut_colors_of, fill_unseen_colors, fill_unseen_layer_opacity, hair_views_of,
                          layer_behind_limbs, layer_reached, layer_through, layer_training_views, limb_views,
                          limbs_over_cloth, mark_outline_cut, occluded_colors_of)

# px of blend weight (over opacity, in one training frame, its surface facing the camera) from
# which a garment-layer Gaussian of the fill's ring counts as reached from outside and keeps its
# decoded colour (docs/loose_clothing.md, "The ring round the seen cloth")
_RING_MIN_REACH = 0.01

if TYPE_CHECKING:
    from ..avatar.state import AvatarState
    from .steps import StepContext


class StagePlan:
    """The interface every stage implements (Stage I's is the whole of ``Stage1Plan``)."""

    stage: int
    settings: StageSettings
    steps: dict[str, TrainingStep]

    def param_groups(self, state: AvatarState) -> list[dict]:
        """Adam parameter groups (``params``, ``lr``, ``name``)."""
        raise NotImplementedError

    def next_kind(self, rng: np.random.Generator) -> str:
        """The kind of the next step (a key of ``steps``)."""
        return "given"

    def status(self, stage_step: int) -> dict:
        """Numbers of the plan at a step of the stage, for the log, the progress bar and the
        studio (e.g. λ_SDS)."""
        return {}

    def after_step(self, context: StepContext) -> str | None:
        """Called after every step of the stage but its last (whose act is ``finish``), with the
        loop: what the plan does to the avatar part way through (Stage I trims the garment layer's
        hem). Returns a line for the log, or None."""
        return None

    def finish(self, context: StepContext) -> str | None:
        """Called once when the stage has used up its steps or minutes (before the final
        evaluation and checkpoint), with the loop (its avatar state and training frames). Returns
        a line for the log, or None."""
        return None

    def state_dict(self) -> dict:
        """What a checkpoint must hold to continue the plan: plain data and tensors only."""
        return {"settings": self.settings.to_dict()}

    def describe(self) -> str:
        s = self.settings
        return f"{s.iters} steps" + (f" or {s.minutes:g} min" if s.minutes else "")


def _unseen_and_filled(state, flags: torch.Tensor, ring_trained: torch.Tensor | None) -> torch.Tensor:
    """``flags`` ((N+M,) bool) made unseen and taken out of the fill's ring, so that the fill repaints
    them: the new ``ring_trained`` (None before: every Gaussian's decoded colour kept in the ring)."""
    state.seen &= ~flags.to(state.seen.device)
    return ~flags if ring_trained is None else ring_trained & ~flags


class Stage1Plan(StagePlan):
    """Stage I (paper Sec. 3.1, Eq. 11): given-view steps on the video, decoder and feature map
    optimised, first hits marked seen."""

    stage = 1

    def __init__(self, config: Stage1Config) -> None:
        self.settings = config
        self.steps = {"given": GivenViewStep(config, marks_seen=True, layer_skinning=True)}
        self._trims_passed: int | None = None  # how many of layer_hem_trims the stage has passed

    def after_step(self, context: StepContext) -> str | None:
        """At each of ``layer_hem_trims`` of the stage: the seen garment-layer Gaussians under the hem
        that drew the legs (``layer_through``'s hem rule) are trimmed off the layer for good, and the
        rest of the stage trains the body under them (``trim_layer_hem``). A run resumed from a
        checkpoint does not redo the trims its stage had passed by steps."""
        trims = self.settings.layer_hem_trims
        if not trims or context.state.model.layer is None:
            return None
        p = context.progress
        if self._trims_passed is None:  # this plan's first step: a resumed stage passed some already,
            # those at or below where its checkpoint stood (by steps: a stage bounded by minutes may
            # redo one its clock had passed, never skip one)
            before = self.settings.progress(context.stage_step - 1, 0.0)
            self._trims_passed = sum(f <= before for f in trims)
        trimmed = 0
        while self._trims_passed < len(trims) and p >= trims[self._trims_passed]:
            self._trims_passed += 1
            trimmed += trim_layer_hem(context.state)
        if not trimmed:
            return None
        return f"Stage I: {trimmed} garment-layer Gaussians under the hem drew the legs: trimmed off the layer"

    def param_groups(self, state: AvatarState) -> list[dict]:
        c = self.settings
        return [{"params": state.model.decoder.parameters(), "lr": c.lr_decoder, "name": "decoder"},
                {"params": [state.model.features], "lr": c.lr_features, "name": "features"},
                *state.model.layer_param_groups(c.lr_features, c.lr_decoder, c.lr_layer_skinning)]  # [] without a layer

    def finish(self, context: StepContext) -> str | None:
        """The seen flags are recounted on the person (``seen_on_person``, train/seen_recount.py) and
        those whose colour training never touched are unmarked (``seen_trained_only``), then the never-seen Gaussians take the wrap-around fill's colours (with hair worn down read in
        the frames: ``AvatarState.hair_colors``) and, on a garment layer, the
        trained cloth's opacity at their height (``fill_unseen``). Last, a garment layer's front and
        back are moved in depth as far as training pulled its sides in (``layer_depth_match``)."""
        state, notes, s = context.state, [], self.settings
        # the avatar's blend weights on the training frames, once, for the recount and the layer
        coverage = (person_coverage(state, context.data, hit_threshold=s.hit_threshold, weights=True)
                    if s.seen_min_weight is not None and (s.seen_on_person or s.fill_unseen) else None)
        not_sources = None
        if s.seen_on_person:
            k = keep_seen_on_person(state, context.data, hit_threshold=s.hit_threshold,
                                    min_weight=s.seen_min_weight, coverage=coverage)
            if k.dropped:
                notes.append(f"{k.dropped} Gaussians seen only off the person's silhouette are unseen")
            if k.added:
                notes.append(f"{k.added} Gaussians the images blended into the person (no first hit) are seen")
            not_sources = k.blended_only  # seen by their blend weight alone: no colour source
        if s.seen_trained_only:
            n = unsee_untrained(state)
            if n:
                notes.append(f"{n} seen Gaussians whose colour training never touched are unseen")
        if s.fill_unseen:
            # the body past the frame's edges: the fills give it the colours at the cut
            state.cut_colors = cut_colors_of(state, context.data)
            past = int(torch.isfinite(state.cut_colors).all(1).sum())
            if past:
                notes.append(f"{past} Gaussians in no training image take the colours where their limbs cross the frame's edge")
            # a part the images cover but never show (a photo's neck under the chin): what they show there
            state.occluded_colors = occluded_colors_of(state, context.data)
            # the layer's opacity first: the colours of the body under the cloth follow the cloth
            # where it is opaque (``layer_cover``)
            n_layer, ring_trained = 0, None
            # what the arms hid in every training frame: the layer's and the body's, read from the
            # same renders
            has_layer = state.model.layer is not None
            hid = (hidden_by_limbs(state, context.data)
                   if s.body_hidden_by_limbs or (s.layer_hidden_by_limbs and has_layer) else None)
            on_layer = torch.arange(state.num_gaussians) >= state.model.num_body
            hidden = hid & on_layer if hid is not None and s.layer_hidden_by_limbs and has_layer else None
            body_hidden = hid & ~on_layer if hid is not None and s.body_hidden_by_limbs else None
            if state.model.layer is not None:
                views = layer_training_views(state, context.data, seen_inside=s.layer_seen_inside,
                                             off_person=s.layer_off_person or s.layer_outline_cut)
                inside = views.get("seen_inside")
                if inside is not None and inside.any():
                    state.seen[state.model.num_body:] &= ~inside.to(state.seen.device)
                    notes.append(f"{int(inside.sum())} garment-layer Gaussians seen only from inside the garment are unseen")
                faced = views["faced"]
                trained = faced.clone()
                if coverage is not None:
                    trained |= layer_reached(state, coverage.total_max, s.seen_min_weight)
                    # the fill's ring keeps the decoded colours the images gave the cloth's outer
                    # side: on the layer, those of Gaussians that faced a camera or that a training
                    # ray reached from outside at all. One seen only from within (the inside of an
                    # open flap at its edge) or never reached has no outer colour of its own: its
                    # colour showed as light specks from behind. Read before the untrained ones
                    # take the cloth's opacity
                    shaped = faced | layer_reached(state, coverage.total_max, _RING_MIN_REACH)
                    ring_trained = torch.cat([torch.ones(state.model.num_body, dtype=torch.bool), shaped.cpu().bool()])
                empty = views.get("off_person") if s.layer_off_person else None
                if s.layer_outline_cut:  # the cloth the outline cut away still hides the body under it
                    n_cut = mark_outline_cut(state, views["off_person"])
                    if n_cut:
                        notes.append(f"{n_cut} garment-layer Gaussians training emptied past the person's outline "
                                     "still hide the body under them from the fill")
                # the training frames the three arm rules read, posed once for all, and the colours
                arms = (limb_views(state, context.data)
                        if s.layer_through or s.layer_behind_limbs or s.limbs_over_cloth else None)
                if s.layer_through:  # no colour source for the layer's unseen side
                    through = layer_through(state, context.data, views=arms)
                    if through is not None and through.any():
                        notes.append(f"{int(through.sum())} garment-layer Gaussians show the body (under the hem, "
                                     "or an arm in front of the cloth), not cloth")
                        not_sources = through if not_sources is None else not_sources | through
                if s.layer_behind_limbs:  # they drew a sleeve or a hand: the fill gives them the cloth's colour
                    behind = layer_behind_limbs(state, context.data, views=arms)
                    if behind is not None and behind.any():
                        state.seen &= ~behind.to(state.seen.device)
                        notes.append(f"{int(behind.sum())} garment-layer Gaussians behind an arm or a hand drew it: "
                                     "they are unseen, filled like the cloth")
                if hidden is not None and hidden.any():
                    # colours mixed with the arm in front: the fill's, read round the gap, and the row's opacity
                    ring_trained = _unseen_and_filled(state, hidden, ring_trained)
                    trained &= ~hidden[state.model.num_body:].to(trained.device)
                    notes.append(f"{int(hidden.sum())} garment-layer Gaussians the arms and hands hid in every "
                                 "training frame are unseen, filled like the cloth")
                if s.limbs_over_cloth:  # they drew the cloth behind them: no colour source for the limb's unseen side
                    over = limbs_over_cloth(state, context.data, views=arms)
                    if over is not None and over.any():
                        notes.append(f"{int(over.sum())} arm and hand Gaussians by the garment layer drew its cloth: "
                                     "no colour source for the limb's unseen side")
                        not_sources = over if not_sources is None else not_sources | over
                n_layer = fill_unseen_layer_opacity(state, trained, empty=empty)
            if body_hidden is not None and body_hidden.any():  # the chest behind folded arms: filled round them
                ring_trained = _unseen_and_filled(state, body_hidden, ring_trained)
                notes.append(f"{int(body_hidden.sum())} body Gaussians the arms and hands hid in every training "
                             "frame are unseen, filled like what surrounds them")
            n = fill_unseen_colors(state, keep_ring=s.fill_unseen_ring, grazing_rule=grazing_rule_for(s),
                                   not_sources=not_sources, ring_trained=ring_trained,
                                   hair_views=hair_views_of(state, context.data), layer_gaps=hidden,
                                   layer_gap_reach=s.layer_gap_reach)
            # Stage II's pseudo-appearance and the editor carry colours from the same sources
            # (``AvatarState.source_flags``)
            state.colour_sources = None if not_sources is None else ~torch.as_tensor(not_sources).cpu().bool()
            if n:
                notes.append(f"{n} Gaussians no training view saw were painted with the seen side's colours")
            hair = 0 if state.hair_colors is None else int(torch.isfinite(state.hair_colors).all(1).sum())
            if hair:
                notes.append(f"{hair} of them behind the head, neck and back took the hair the images show falling")
            if n_layer:
                notes.append(f"{n_layer} garment-layer Gaussians no training camera faced took the trained cloth's opacity at their height")
        if s.layer_depth_match and state.model.layer is not None:
            # after the fills, which read the layer's built positions
            match = match_layer_depth(state.model)
            if match is not None:
                notes.append(match.describe())
        return "Stage I: " + "; ".join(notes) if notes else None
