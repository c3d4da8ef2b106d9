"""The dual-space guidance step (paper Sec. 3.2, Eq. 5): the avatar rendered from a selected unseen
view -- in canonical space (reference: the Stage I canonical front render) or in observation space
at a reference video frame (reference: that frame) -- cropped to the body and resized to the
prior's input size (A.3), guided by the prior and weighted by λ_SDS(t) (Eq. 14).

Unseen-view normals: the paper inpaints back normals with d-BiNI and IF-Nets. Neither is available
here; the substitute is the body model's own surface normals: the normals of the Gaussians that
propagation does not trust as seen are pulled towards the posed body normals
(λ_unseen_normal), the trusted ones towards their current values.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch
import torch.nn.functional as F

from ..body.lbs import apply_normals
from ..camera import Camera
from ..priors.base import CameraDelta, GuidanceInput, GuidancePrior
from ..raster import rasterization
from ..train import losses as L
from ..train.render import crop_camera, render_avatar
from ..train.steps import StepContext, StepOutcome, TrainingStep, gaussians_finite

if TYPE_CHECKING:
    from .config import Stage2Config
    from .view_selection import CandidateView


class GuidancePlan(Protocol):
    """What a guidance step reads from its stage's plan (``Stage2Plan`` is one): the settings, the
    selected views, the reference images, the propagated pseudo-colours and the λ_SDS schedule."""

    settings: Stage2Config
    guidance_background: torch.Tensor
    pseudo_colors: torch.Tensor | None

    def pick_view(self, space: str, rng: np.random.Generator) -> tuple[object, CandidateView]: ...

    def reference_image(self, trainer: StepContext, frame: int | None) -> torch.Tensor: ...

    def sds_weight(self, stage_step: int) -> float: ...


class Stage2Error(ValueError):
    pass


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


def square_crop(image: np.ndarray, mask: np.ndarray, size: int, background, margin: float = 0.08) -> torch.Tensor:
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


class GuidanceStep(TrainingStep):
    """A guidance step in one space ("canonical" or "observation") on the plan's selected views."""

    def __init__(self, space: str, plan: GuidancePlan, prior: GuidancePrior) -> None:
        self.kind = space
        self.plan = plan
        self.prior = prior

    def __call__(self, trainer: StepContext) -> StepOutcome:
        plan, state, s2 = self.plan, trainer.state, self.plan.settings
        device = state.device
        sv, view = plan.pick_view(self.kind, trainer.rng)
        frame = sv.frame
        canon, pose_features = state.decode(frame)
        if frame is None:
            posed = state.model.splats(canon)
            body_normals = state.model.base_normals
        else:
            M = state.model.lbs_matrices(state.frame_transforms(frame))
            posed = state.model.pose_with(canon, M)
            body_normals = apply_normals(M, state.model.base_normals)
        index = -1 if frame is None else frame
        if not gaussians_finite(posed):
            return StepOutcome(index, skipped=True)
        camera = framed_camera(view.camera, posed.means, s2.prior_size)
        background = plan.guidance_background
        r = render_avatar(posed, camera, background, normals=s2.unseen_normals)
        render = r.rgb
        clip = s2.sds_grad_clip
        if render.requires_grad and clip > 0:
            render.register_hook(lambda g: g * (clip / g.norm().clamp_min(clip)))
        trusted = state.trusted_seen.to(device)[:, None]
        targets: list[torch.Tensor] = []

        def detached_targets() -> torch.Tensor:
            """One render without gradients, with the avatar's current geometry, of the propagated
            colours (channels 0-2: the built-in prior's pseudo-target) and the unseen-normal targets
            in camera space (channels 3-5)."""
            if not targets:
                with torch.no_grad():
                    R = torch.as_tensor(camera.R, dtype=posed.normals.dtype, device=device)
                    n_target = torch.where(trusted, posed.normals, body_normals) @ R.T
                    bg = torch.cat([background, torch.zeros(3, device=device)])
                    targets.append(rasterization(posed.means.detach(), posed.quats, posed.scales.detach(),
                                                 posed.opacities, torch.cat([plan.pseudo_colors, n_target], 1),
                                                 camera, background=bg).image)
            return targets[0]

        delta = CameraDelta(polar=-math.radians(view.elevation_deg - sv.reference_elevation),
                            azimuth=math.radians(view.azimuth_deg), radius=0.0,
                            reference_polar=math.radians(90.0 - sv.reference_elevation))
        guidance = self.prior.loss(GuidanceInput(render.clamp(0, 1), plan.reference_image(trainer, frame), delta,
                                                 progress=trainer.progress, alpha=r.alpha, space=self.kind,
                                                 pseudo_target=lambda: detached_targets()[..., :3]))
        w = plan.sds_weight(trainer.stage_step)
        terms = {"sds": guidance.loss}
        weights = {"sds": w}
        if s2.unseen_normals and r.normal is not None:
            terms["unseen_normal"] = L.mse(r.normal, detached_targets()[..., 3:])
            weights["unseen_normal"] = s2.lambda_unseen_normal * (w / s2.lambda_sds if s2.lambda_sds > 0 else 0.0)
        if s2.lambda_pseudo_color > 0 and plan.pseudo_colors is not None and s2.prior == "builtin":
            # the same pseudo-appearance in texture space (every Gaussian each step, not only those
            # this view shows): the repainted ones towards the propagated colours and, with
            # pseudo_color_all, the trusted ones towards their Stage I colours (as in the render target)
            free = torch.ones_like(state.trusted_seen, device=device) if s2.pseudo_color_all \
                else ~state.trusted_seen.to(device)
            if bool(free.any()):
                terms["pseudo_color"] = L.mse(canon.colors[free], plan.pseudo_colors[free])
                weights["pseudo_color"] = s2.lambda_pseudo_color * (w / s2.lambda_sds if s2.lambda_sds > 0 else 0.0)
        if pose_features is not None:
            terms["pose_features"] = L.mean_square(pose_features)
            weights["pose_features"] = s2.lambda_pose_features
        info = {"view_azimuth": view.azimuth_deg, "view_elevation": view.elevation_deg, **guidance.info,
                f"{self.kind}_sds": float(guidance.loss.detach())}
        return StepOutcome(index, terms, weights, info=info)
