"""Pose feature injection (paper Eq. 12-13): a small UNet over the posed UV positional map whose
output P replaces the second S in the decoder input G([S, P]).

Input: the articulation of the body at each texel of the Gaussians' UV map, as the displacement
of the posed surface (global rotation and translation removed) from the canonical surface, so
the map is zero in the canonical pose. Output: a (1, C, R_S, R_S) map at the resolution of S.

P = S + E(P_uv). The encoder's last layer starts at zero, so Stage II begins exactly where Stage I
ended (G([S, S])) instead of feeding the trained decoder an input it never saw; the Frobenius
regulariser λ_p of Eq. 16 acts on the pose-dependent part E(P_uv).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.GroupNorm(min(8, cout), cout), nn.SiLU(),
                         nn.Conv2d(cout, cout, 3, padding=1), nn.GroupNorm(min(8, cout), cout), nn.SiLU())


class PoseEncoder(nn.Module):
    """UNet: 3-channel posed-displacement map (R x R) -> ``out_channels`` feature map (out_res x out_res)."""

    def __init__(self, out_channels: int, out_resolution: int, width: int = 16, depth: int = 3,
                 input_scale: float = 10.0) -> None:
        super().__init__()
        self.out_resolution = out_resolution
        self.input_scale = input_scale  # displacements are tenths of a metre: bring them to O(1)
        widths = [width * 2 ** i for i in range(depth)]
        self.down = nn.ModuleList()
        cin = 3
        for w in widths:
            self.down.append(_block(cin, w))
            cin = w
        self.up = nn.ModuleList()
        for w in reversed(widths[:-1]):
            self.up.append(_block(cin + w, w))
            cin = w
        self.head = nn.Conv2d(cin, out_channels, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, pose_map: torch.Tensor) -> torch.Tensor:
        if pose_map.dim() == 3:
            pose_map = pose_map[None]
        if pose_map.shape[1] != 3:
            raise ValueError(f"pose encoder expects a (1,3,R,R) posed positional map, found {tuple(pose_map.shape)}")
        h = pose_map * self.input_scale
        skips = []
        for i, block in enumerate(self.down):
            if i:
                h = F.avg_pool2d(h, 2)
            h = block(h)
            skips.append(h)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            h = F.interpolate(h, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            h = block(torch.cat([h, skip], dim=1))
        out = self.head(h)
        if out.shape[-1] != self.out_resolution:
            out = F.interpolate(out, size=(self.out_resolution, self.out_resolution), mode="bilinear",
                                align_corners=False)
        return out
