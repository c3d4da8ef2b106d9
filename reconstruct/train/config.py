"""Training configuration with the paper's defaults (Appendix A.1) and this machine's sizes."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ..avatar.config import AvatarConfig


@dataclass
class Stage1Config:
    # length: whichever comes first
    iters: int = 6000
    minutes: float | None = None
    # loss weights (paper Appendix A.1.3)
    lambda_rgb: float = 0.8
    lambda_normal: float = 0.8
    lambda_ssim: float = 0.2
    lambda_lpips: float = 0.2
    lambda_offset: float = 0.85
    lambda_scale: float = 0.03
    lambda_features: float = 1.0
    # optimiser (GaussianAvatar: Adam, decoder 3e-3, feature map 5e-4, x0.1 at 1/3 and 2/3 of the run)
    lr_decoder: float = 3e-3
    lr_features: float = 5e-4
    lr_milestones: tuple[float, ...] = (1 / 3, 2 / 3)
    lr_gamma: float = 0.1
    # per-frame pose refinement (paper: on for in-the-wild videos, off where poses are accurate)
    pose_refinement: bool = False
    lr_pose: float = 5e-3
    pose_refinement_start: float = 0.1  # fraction of the run before poses are optimised
    # images
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    crop_margin: int = 16  # render and compare only the body's box (plus margin) of each frame
    # LPIPS (only when the user supplies weights)
    lpips_net: str = "alex"
    lpips_backbone: str | None = None
    lpips_lin: str | None = None
    # visibility (paper Eq. 7): a Gaussian is seen when it is the first hit with alpha >= this
    hit_threshold: float = 0.5
    # bookkeeping
    eval_every_seconds: float = 60.0
    checkpoint_every_seconds: float = 120.0
    seed: int = 0
    threads: int | None = None
    device: str = "cpu"
    avatar: AvatarConfig = field(default_factory=AvatarConfig)

    def __post_init__(self) -> None:
        if self.iters < 1:
            raise ValueError(f"--iters must be at least 1, found {self.iters}")
        if self.minutes is not None and self.minutes <= 0:
            raise ValueError(f"--minutes must be positive, found {self.minutes}")
        if isinstance(self.avatar, dict):
            self.avatar = AvatarConfig(**self.avatar)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Stage1Config":
        return config_from_dict(cls, d, "Stage I")


def config_from_dict(cls, d: dict, what: str):
    """A config dataclass from its ``to_dict()`` (JSON turns tuples into lists): unknown keys are an
    error naming them; list values of tuple-typed fields become tuples again."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(d) - set(fields)
    if unknown:
        raise ValueError(f"unknown {what} settings {sorted(unknown)}")
    d = {k: (tuple(v) if isinstance(v, list) and str(fields[k].type).startswith("tuple") else v) for k, v in d.items()}
    return cls(**d)
