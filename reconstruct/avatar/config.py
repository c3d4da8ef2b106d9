"""Avatar model configuration (paper Sec. 3.1, Appendix A.1; GaussianAvatar's channel counts)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class AvatarConfig:
    feature_channels: int = 64  # channels of the canonical feature map S (GaussianAvatar c_geom)
    feature_resolution: int = 128  # S is 128 x 128 (paper)
    gaussian_resolution: int = 128  # one Gaussian per valid texel of this positional map (paper: 512; CPU default 128)
    hidden: int = 128  # decoder width (GaussianAvatar hsize)
    trunk_layers: int = 8  # paper: 8-layer MLP, skip from the input into the 4th layer
    skip_layer: int = 4
    head_layers: int = 2  # each head is a 2-layer MLP
    offset_scale: float = 0.02  # metres per unit of the Δx head (GaussianAvatar)
    scale_range: float = 3.0  # a Gaussian's std is at most this multiple of its own texel spacing
    init_scale_factor: float = 0.6  # initial std as a fraction of its texel spacing
    feature_init_std: float = 0.01
    pose_feature_channels: int = 64  # P channels in Stage II (same as S so [S,P] has the Stage I width)

    def __post_init__(self) -> None:
        for name in ("feature_channels", "feature_resolution", "gaussian_resolution", "hidden", "trunk_layers"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"AvatarConfig.{name} must be positive, found {getattr(self, name)}")
        if not 1 <= self.skip_layer < self.trunk_layers:
            raise ValueError(f"AvatarConfig.skip_layer must be in [1, {self.trunk_layers}), found {self.skip_layer}")
        if not 0 < self.init_scale_factor < self.scale_range:
            raise ValueError(f"AvatarConfig: need 0 < init_scale_factor < scale_range, found "
                             f"{self.init_scale_factor} and {self.scale_range}")
        if self.pose_feature_channels != self.feature_channels:
            raise ValueError("AvatarConfig.pose_feature_channels must equal feature_channels: P replaces the second S")
