"""Step kinds: one small interface for what a training step computes.

A step looks at the trainer (avatar state, training data, random generator, the stage's progress)
and returns a ``StepOutcome``: the loss terms and their weights, the frame it used, and what to do
once the update is taken. The trainer owns everything else: the optimisers, the learning-rate
schedule, the guards against non-finite numbers, the clocks and the logs. In the spirit of
gsplat's ``Strategy``: policy in small objects, the loop outside.

``GivenViewStep`` is the Stage I loss on a video frame (paper Eq. 11); Stage II adds the guidance
step (``reconstruct.stage2.guidance``). With a garment layer it adds an alpha-vs-mask term and the
layer's sheet regulariser (docs/loose_clothing.md).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable, Protocol

import torch

from ..avatar.garment_layer import neighbour_strain
from . import losses as L
from .config import Stage1Config
from .data import composite_on
from .layer_cover import view_cover_term
from .render import render_avatar

if TYPE_CHECKING:
    import numpy as np

    from ..avatar.state import AvatarState
    from .data import TrainingData


class StepContext(Protocol):
    """What a training step reads from the loop that runs it (the ``Trainer`` is one): the avatar,
    the training images, where the stage is, and its random numbers."""

    state: AvatarState
    data: TrainingData
    lpips: object | None
    rng: np.random.Generator
    stage_step: int
    device: torch.device

    @property
    def progress(self) -> float: ...

    def next_frame(self) -> int: ...


@dataclass
class StepOutcome:
    frame: int  # the video frame used (-1: canonical space)
    terms: dict[str, torch.Tensor] = field(default_factory=dict)  # unweighted loss terms
    weights: dict[str, float] = field(default_factory=dict)
    refine_poses: bool = False  # whether the pose corrections take part in this update
    info: dict = field(default_factory=dict)  # numbers for the metrics log
    after_update: Callable[[], None] | None = None  # bookkeeping once the update is taken
    skipped: bool = False  # non-finite Gaussians: nothing to update

    def loss(self) -> torch.Tensor:
        return sum(self.weights[k] * v for k, v in self.terms.items())


def gaussians_finite(g) -> bool:
    """Whether posed Gaussians are all finite (a bad decoder output or pose must not reach the
    rasterizer, whose input check would stop the run)."""
    return all(bool(torch.isfinite(t).all()) for t in (g.means, g.scales, g.colors, g.normals, g.opacities))


class _ScatteredPositions:
    """Means and normals of a subset of the Gaussians placed at their indices in full-size arrays
    (what ``AvatarState.mark_seen`` looks up by Gaussian id)."""

    def __init__(self, posed, index: torch.Tensor, n: int) -> None:
        self.means = posed.means.detach().new_zeros(n, 3).index_copy(0, index, posed.means.detach())
        self.normals = posed.normals.detach().new_zeros(n, 3).index_copy(0, index, posed.normals.detach())


class TrainingStep(ABC):
    kind: str

    @abstractmethod
    def __call__(self, trainer: StepContext) -> StepOutcome:
        ...


class GivenViewStep(TrainingStep):
    """Paper Eq. 11 on a video frame: RGB, SSIM, normals, LPIPS (with weights), the Frobenius
    regularisers of Δx, s and S, plus λ_p‖E(P_uv)‖ when the avatar has pose injection (Eq. 16).
    With a garment layer also: rendered alpha against the mask (``lambda_alpha``: the layer's
    opacities learn the silhouette) and the layer's neighbour-distance regulariser over the grid
    edges among the decoded Gaussians (``lambda_layer_spacing``).
    ``marks_seen``: first-hit Gaussians that face the camera become seen (Eq. 7, Stage I).
    ``layer_skinning``: the layer's skinning is trained (Stage I with ``lr_layer_skinning`` > 0), so
    its prior is added (``lambda_layer_skinning``).
    ``layer_colour_outside``: a garment-layer Gaussian the view sees from inside the garment
    (``AvatarModel.layer_seen_from_inside``) gets no colour gradient from it (Stage II): it has one
    colour for both sides, and its outside is the prior's."""

    kind = "given"

    def __init__(self, config: Stage1Config, *, marks_seen: bool = True, lambda_pose_features: float = 0.0,
                 layer_skinning: bool = False, layer_colour_outside: bool = False) -> None:
        self.config = config
        self.marks_seen = marks_seen
        self.layer_colour_outside = layer_colour_outside
        self.layer_skinning = layer_skinning and config.lr_layer_skinning > 0
        self.lambda_pose_features = lambda_pose_features

    def __call__(self, trainer: StepContext) -> StepOutcome:
        cfg, state, data = self.config, trainer.state, trainer.data
        i = trainer.next_frame()
        tgt = data.targets[i]
        refine = state.refine_poses and trainer.progress >= cfg.pose_refinement_start
        transforms = state.frame_transforms(i, refined=refine)
        model = state.model
        # decode only what this view can show: Gaussians on the far side of the body are skipped
        margin = getattr(cfg, "cull_backfacing", None)
        matrices = model.lbs_matrices(transforms)
        index = None if margin is None else model.facing(matrices, tgt.camera.center, margin)
        # state.decode(i) for the chosen Gaussians (with the edits: locked texels keep their attributes)
        canon, pose_features = state.decode(i, index=index)
        posed = model.pose_with(canon, matrices if index is None else matrices[index], model.clearance_matrices(matrices),
                                model.layer_stretch_of(matrices))
        if not gaussians_finite(posed):
            return StepOutcome(i, skipped=True)
        if self.layer_colour_outside and model.num_layer:
            inside = model.layer_seen_from_inside(matrices, tgt.camera.center, index)
            posed = replace(posed, colors=torch.where(inside[:, None], posed.colors.detach(), posed.colors))
        background, image = data.background, tgt.image
        if cfg.random_background:
            # from the loop's own generator (saved in checkpoints), not torch's global one
            background = torch.as_tensor(trainer.rng.random(3), dtype=image.dtype, device=image.device)
            image = composite_on(tgt, background, data.background)
        r = render_avatar(posed, tgt.camera, background, normals=data.use_normals, first_hit=self.marks_seen,
                          hit_threshold=cfg.hit_threshold)
        terms = {
            "rgb": L.mse(r.rgb, image),
            "ssim": L.ssim_loss(r.rgb, image),
            "offset": L.mean_square(canon.offsets_raw),
            "scale": L.mean_square(canon.scales),
            "features": L.mean_square(canon.features),
        }
        weights = {"rgb": cfg.lambda_rgb, "ssim": cfg.lambda_ssim, "offset": cfg.lambda_offset,
                   "scale": cfg.lambda_scale, "features": cfg.lambda_features}
        if data.use_normals and tgt.normal is not None:
            terms["normal"] = L.mse(r.normal, tgt.normal)
            weights["normal"] = cfg.lambda_normal
        elif cfg.lambda_normal_prior:
            base = model.base_normals if canon.index is None else model.base_normals[canon.index]
            terms["normal_prior"] = L.normal_deviation(canon.normals, base)
            weights["normal_prior"] = cfg.lambda_normal_prior
        if trainer.lpips is not None:
            terms["lpips"] = trainer.lpips(r.rgb[None].clamp(0, 1), image[None]).mean()
            weights["lpips"] = cfg.lambda_lpips
        if pose_features is not None:
            terms["pose_features"] = L.mean_square(pose_features)
            weights["pose_features"] = self.lambda_pose_features
        if model.num_layer:
            terms["alpha"] = L.mse(r.alpha, tgt.mask)
            weights["alpha"] = cfg.lambda_alpha
            edges, rest = model.layer_edge_rows(index)
            terms["layer_spacing"] = neighbour_strain(canon.means, edges, rest)
            weights["layer_spacing"] = cfg.lambda_layer_spacing
            if self.layer_skinning:
                terms["layer_skinning"] = model.layer_skinning_prior()
                weights["layer_skinning"] = cfg.lambda_layer_skinning
            if cfg.lambda_layer_opaque:
                terms["layer_opaque"] = (1.0 - model.opacities()[model.num_body:]).mean()
                weights["layer_opaque"] = cfg.lambda_layer_opaque
            if cfg.lambda_layer_cover:
                cover = view_cover_term(model, posed.means, index, tgt.camera, tgt.inner_mask(cfg.layer_cover_inset))
                if cover is not None:
                    terms["layer_cover"] = cover
                    weights["layer_cover"] = cfg.lambda_layer_cover
        info = {"psnr_train": float(-10 * torch.log10(terms["rgb"].detach().clamp_min(1e-12)))}
        after = None
        if self.marks_seen:
            def after() -> None:
                hits = r.first_hit if index is None else torch.where(r.first_hit >= 0, index[r.first_hit.clamp_min(0)], -1)
                full = posed if index is None else _ScatteredPositions(posed, index, state.num_gaussians)
                state.mark_seen(hits, full, tgt.camera)
        info["gaussians_decoded"] = int(state.num_gaussians if index is None else len(index))
        return StepOutcome(i, terms, weights, refine_poses=refine, info=info, after_update=after)
