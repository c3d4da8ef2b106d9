"""Stage II configuration with the paper's defaults (Sec. 3.2-3.3, Appendix A.2).

Stage II continues a Stage I run: the Stage I loss (its weights come from the run's Stage I
settings) plus λ_p‖P‖ and λ_SDS (L_SDS^o + L_SDS^c) on the selected unseen views.

Epochs. The paper halves λ_SDS every k = 100 epochs from t0 = 100 (Eq. 14) over a 3-hour GPU
run. A CPU run here is several hundred steps, so the schedule counts *schedule epochs* of
``epoch_steps`` steps each (default 2: λ_SDS,0 until step 400, halved at 400, 600, 800, ...);
set ``epoch_steps`` to the number of frames to count true epochs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ..schedule import Scheduled
from ..train.config import StageSettings

PRIORS = ("builtin", "zero123")
PROPAGATIONS = ("wrap", "diffusion")


@dataclass
class Stage2Config(StageSettings):
    # length (StageSettings): whichever of iters and minutes comes first
    iters: int = 800
    # the split of each epoch (A.2.1): given-view training vs dual-space SDS, canonical vs observation
    given_view_ratio: float = 0.5
    canonical_ratio: float = 0.5
    canonical_sds: bool = True
    observation_sds: bool = True
    # losses (A.2.1)
    lambda_sds: float = 0.3  # λ_SDS,0
    lambda_pose_features: float = 0.5  # λ_p, Frobenius regulariser of the pose features P
    lambda_unseen_normal: float = 0.8  # body-model normals as unseen-view normal targets (see DESIGN.md)
    unseen_normals: bool = True
    # built-in prior: weight of its pseudo-appearance applied in texture space as well (the colours
    # of the untrusted Gaussians towards the propagated ones; scheduled with λ_SDS; 0 = renders only).
    # Off by default: at 1.0 on 150-step runs (docs/stage2.md) it gained +0.31 dB unseen on seed 1
    # but cost seed 0 0.59 dB on seen views; renders alone gained +0.48 / +0.20 with no seen loss
    lambda_pseudo_color: float = 0.0
    pseudo_color_all: bool = False  # ... on every Gaussian (trusted ones: their Stage I colours), not only untrusted
    # the given-view steps colour a garment-layer Gaussian only from the side its surface faces
    # (the layer's own normal, posed): one seen from inside the garment -- the inside of a coat's
    # back through a gap in its front, a flared hem's lining -- has one colour for both sides, and
    # the view from inside painted its colour onto the outside the prior gave it. The coat photo's
    # back came out mottled, with a spot of the scarf's orange; with the rule it keeps the fill's
    # smooth cloth, and its training view stays at Stage I's fit (26.41 -> 26.15 dB in the mask,
    # Stage I 26.16). Coat seed 1 after Stage II: 33.54 / 28.50 -> 33.53 / 28.48 dB x2 (steps.py)
    layer_colour_outside: bool = True
    # progressive schedule (Eq. 14): λ_SDS(t) = λ_SDS,0 / 2^floor((t - t0) / k) for t >= t0
    progressive: bool = True
    sds_t0: float = 100.0
    sds_k: float = 100.0
    epoch_steps: float = 2.0
    # pose feature injection (Eq. 12-13)
    pose_injection: bool = True
    pose_encoder_width: int = 16  # channels of the UNet's first level (doubling per level)
    # view selection (Eq. 8-10, A.2.2)
    view_selection: bool = True  # False: SDS on views drawn from all candidates
    visibility_threshold: float = 0.5
    # Seen flags are shrunk by this many texels on the UV grid before visibility maps and
    # propagation: first-hit marking leaves isolated seen specks on the back and marks grazing
    # boundary Gaussians (0 = the raw flags of Eq. 7). On the default scene the back view's visible
    # share is 0.53 with the raw flags (nothing selected at 0.5) and 0.25 after 2 texels.
    seen_erosion: int = 2
    num_azimuths: int = 100
    overhead_elevation_deg: float = 80.0
    # the prior
    prior: str = "builtin"
    # the built-in prior's pseudo-appearance: "wrap" (garment colours carried round at the same
    # height, front-only details left out; wrap_fill.py) or "diffusion" (the earlier screened
    # harmonic fill pulled towards the mirrored front; propagation.py)
    propagation: str = "wrap"
    prior_path: str | None = None
    prior_size: int = 256  # crops resized to this for the prior (A.3)
    guidance_scale: float = 3.0  # classifier-free guidance (zero123)
    sds_grad_clip: float = 1.0  # max gradient norm on the SDS-weighted render gradient
    # optimiser: the unseen appearance is learnt mostly in the per-texel features S (local); the
    # shared decoder moves slowly so the seen views keep their Stage I quality. Measured on the
    # default scene (300 steps): decoder/features 3e-4/5e-5 gave unseen +0.93 dB, seen -0.18 dB;
    # 1e-4/5e-4 gave unseen +1.24 dB, seen -0.30 dB; 1e-3/2e-4 lost 1 dB on seen views. Since
    # Stage I fills its unseen side and converges (discs, budget-shaped schedule), features at
    # 5e-4 -- ten times the rate Stage I ends at -- cost seen views: seed 0, 20-minute Stage I,
    # 300 Stage II steps: 5e-4 seen -0.63 dB / unseen +0.29 dB; 5e-5 seen -0.14 / unseen +0.18.
    # So Stage II's features go on at Stage I's final rate (lr_features x lr_final).
    lr_decoder: float = 1e-4
    lr_features: float = 5e-5
    lr_pose_encoder: float = 1e-4
    lr_milestones: tuple[float, ...] = (2 / 3,)  # x lr_gamma after these fractions of Stage II
    # bookkeeping
    seed: int = 0

    label: ClassVar[str] = "Stage II "

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("given_view_ratio", "canonical_ratio"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"Stage II {name} must be in [0, 1], found {v}")
        if not 0.0 < self.visibility_threshold < 1.0:
            raise ValueError(f"visibility threshold must be in (0, 1), found {self.visibility_threshold}")
        if self.sds_k <= 0:
            raise ValueError(f"SDS halving interval k must be positive, found {self.sds_k}")
        if self.seen_erosion < 0:
            raise ValueError(f"seen_erosion must be >= 0, found {self.seen_erosion}")
        if not self.epoch_steps > 0:
            raise ValueError(f"epoch_steps must be positive, found {self.epoch_steps}")
        if self.prior not in PRIORS:
            raise ValueError(f"unknown prior {self.prior!r}; choose one of {', '.join(PRIORS)}")
        if self.propagation not in PROPAGATIONS:
            raise ValueError(f"unknown propagation {self.propagation!r}; choose one of {', '.join(PROPAGATIONS)}")
        if self.prior == "zero123" and not self.prior_path:
            raise ValueError("the zero123 prior needs --prior-path DIR (a diffusers-format Zero123 folder)")
        if self.lambda_sds < 0 or self.lambda_pose_features < 0:
            raise ValueError("Stage II loss weights must be non-negative")

    @classmethod
    def from_dict(cls, d: dict):
        """Settings recorded by a run; records older than a setting get the value that run used."""
        d = dict(d)
        d.setdefault("layer_colour_outside", False)  # recorded before the layer was coloured from outside only
        return super().from_dict(d)

    def sds_schedule(self) -> Scheduled:
        """λ_SDS over schedule epochs (Eq. 14), or the constant λ_SDS,0."""
        if not self.progressive:
            return Scheduled.constant(self.lambda_sds)
        return Scheduled.halving(self.lambda_sds, self.sds_t0, self.sds_k)

    def sds_weight(self, step: int) -> float:
        """λ_SDS at a Stage II step."""
        return self.sds_schedule().value(step / self.epoch_steps)
