"""The animatable Gaussian avatar: canonical feature map S, decoder G, LBS to observation space.

One Gaussian sits on each valid texel of the canonical positional UV map (paper A.1.1). Its
decoder input is [S(uv), S(uv), uv] in Stage I and [S(uv), P(uv), uv] in Stage II (Eq. 1, 12):
the feature maps are sampled bilinearly at the texel's UV. Outputs: x_c = x + Δx, n_c = n + Δn
(renormalised), colour, isotropic scale; opacity 1 and rotation identity (fixed, as the paper).
Scales are relative to each Gaussian's own texel spacing, which varies by a factor of three over
the body (the atlas gives the head more texels per area than the shins): a global scale leaves
holes in sparse parts that rays pass through.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..body.base import BodyModel
from ..body.lbs import apply_normals, apply_points, blend
from ..body.uv_map import UVMap, build_uv_map, texel_spacing
from .config import AvatarConfig
from .decoder import GaussianDecoder
from .pose_encoder import PoseEncoder


@dataclass
class CanonicalGaussians:
    means: torch.Tensor  # (N,3) x_c
    normals: torch.Tensor  # (N,3) n_c, unit
    colors: torch.Tensor  # (N,3) in [0,1]
    scales: torch.Tensor  # (N,3) standard deviations (isotropic)
    offsets_raw: torch.Tensor  # (N,3) Δx in head units (Δx = offset_scale * raw): the regulariser's input
    features: torch.Tensor  # the feature map S that produced them (for its regulariser)


@dataclass
class PosedGaussians:
    means: torch.Tensor
    normals: torch.Tensor
    colors: torch.Tensor
    scales: torch.Tensor
    quats: torch.Tensor
    opacities: torch.Tensor


class AvatarModel(nn.Module):
    def __init__(self, body: BodyModel, config: AvatarConfig | None = None, uv_map: UVMap | None = None) -> None:
        super().__init__()
        self.config = config = config or AvatarConfig()
        uv = uv_map or build_uv_map(body, config.gaussian_resolution)
        if uv.resolution != config.gaussian_resolution:
            raise ValueError(f"UV map resolution {uv.resolution} != AvatarConfig.gaussian_resolution {config.gaussian_resolution}")
        self.uv_map = uv
        self.body_name = body.name
        R = uv.resolution
        rc = torch.as_tensor(uv.texel_rc, dtype=torch.float32)
        grid = torch.stack([(rc[:, 1] + 0.5) / R * 2 - 1, (rc[:, 0] + 0.5) / R * 2 - 1], dim=1)
        self.register_buffer("uv_grid", grid)  # (N,2) grid_sample coordinates (x = column, y = row)
        self.register_buffer("base_positions", uv.positions.float())
        self.register_buffer("base_normals", uv.normals.float())
        self.register_buffer("skin_weights", uv.weights.float())
        canonical_inverse = torch.linalg.inv(blend(uv.weights, body.canonical_transforms))
        self.register_buffer("canonical_inverse", canonical_inverse.float())
        spacing = texel_spacing(uv).float()
        self.register_buffer("texel_spacing", spacing)
        C, Rf = config.feature_channels, config.feature_resolution
        self.features = nn.Parameter(torch.randn(1, C, Rf, Rf) * config.feature_init_std)
        self.decoder = GaussianDecoder(2 * C + 2, config.hidden, config.trunk_layers, config.skip_layer, config.head_layers)
        init = config.init_scale_factor / config.scale_range
        with torch.no_grad():
            self.decoder.heads["scale"][-1].bias.fill_(math.log(init / (1 - init)))
        self.pose_encoder: nn.Module | None = None

    @property
    def num_gaussians(self) -> int:
        return int(self.base_positions.shape[0])

    def sample(self, feature_map: torch.Tensor) -> torch.Tensor:
        """(1,C,H,W) map sampled bilinearly at every Gaussian's texel -> (N,C)."""
        out = F.grid_sample(feature_map, self.uv_grid[None, None], mode="bilinear", align_corners=False)
        return out[0, :, 0].T

    def decoder_input(self, pose_features: torch.Tensor | None = None) -> torch.Tensor:
        """[S, S, uv] (Stage I) or [S, P, uv] with P = S + ``pose_features`` (Stage II, Eq. 12)."""
        s = self.sample(self.features)
        second = s if pose_features is None else self.sample(self.features + pose_features)
        return torch.cat([s, second, self.uv_grid], dim=1)

    # ----- pose feature injection (Stage II) ------------------------------------------------
    def enable_pose_injection(self, width: int = 16) -> PoseEncoder:
        if self.pose_encoder is None:
            self.pose_encoder = PoseEncoder(self.config.feature_channels, self.config.feature_resolution,
                                            width).to(self.features.device)
        return self.pose_encoder

    def pose_map(self, articulation: torch.Tensor) -> torch.Tensor:
        """(3,R,R) posed positional map (Eq. 13's P_uv) for bone transforms ``articulation`` of a pose
        without its global rotation and translation: the displacement of each texel's surface point
        from its canonical position (zero in the canonical pose)."""
        M = self.lbs_matrices(articulation)
        return self.uv_map.scatter(apply_points(M, self.base_positions) - self.base_positions)

    def pose_features(self, articulation: torch.Tensor) -> torch.Tensor | None:
        """E(P_uv), the pose-dependent part of P, or None without pose injection."""
        if self.pose_encoder is None:
            return None
        return self.pose_encoder(self.pose_map(articulation)[None])

    def canonical(self, pose_features: torch.Tensor | None = None) -> CanonicalGaussians:
        out = self.decoder(self.decoder_input(pose_features))
        cfg = self.config
        means = self.base_positions + cfg.offset_scale * out["offset"]
        normals = F.normalize(self.base_normals + out["normal_offset"], dim=1, eps=1e-8)
        colors = torch.sigmoid(out["color"])
        scales = (cfg.scale_range * self.texel_spacing[:, None] * torch.sigmoid(out["scale"])).expand(-1, 3)
        return CanonicalGaussians(means, normals, colors, scales, out["offset"], self.features)

    def lbs_matrices(self, pose_transforms: torch.Tensor) -> torch.Tensor:
        """Per-Gaussian canonical -> observation matrices (N,4,4) for bone transforms (J,4,4)."""
        return blend(self.skin_weights, pose_transforms.to(self.skin_weights)) @ self.canonical_inverse

    def pose(self, canon: CanonicalGaussians, pose_transforms: torch.Tensor) -> PosedGaussians:
        return self.pose_with(canon, self.lbs_matrices(pose_transforms))

    def pose_with(self, canon: CanonicalGaussians, matrices: torch.Tensor) -> PosedGaussians:
        """The Gaussians moved by per-Gaussian LBS ``matrices`` (N,4,4) (``lbs_matrices``)."""
        return self.splats(canon, apply_points(matrices, canon.means), apply_normals(matrices, canon.normals))

    @staticmethod
    def splats(canon: CanonicalGaussians, means: torch.Tensor | None = None,
               normals: torch.Tensor | None = None) -> PosedGaussians:
        """Renderable Gaussians at ``means``/``normals`` (default: the canonical ones, i.e. canonical
        space), with the fixed identity rotation and opacity 1 (paper A.1)."""
        means = canon.means if means is None else means
        n = means.shape[0]
        quats = torch.zeros(n, 4, dtype=means.dtype, device=means.device)
        quats[:, 0] = 1.0
        return PosedGaussians(means, canon.normals if normals is None else normals, canon.colors, canon.scales, quats,
                              torch.ones(n, dtype=means.dtype, device=means.device))

    def parts(self) -> np.ndarray:
        return self.uv_map.parts
