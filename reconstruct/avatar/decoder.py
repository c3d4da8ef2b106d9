"""The Gaussian decoder G (paper Eq. 1, 12; Appendix A.1.2): a per-Gaussian MLP over [S, S] (Stage I)
or [S, P] (Stage II) plus the texel's UV coordinates, with four heads Δx, Δn, colour and scale."""

from __future__ import annotations

import torch
from torch import nn


def _mlp(sizes: list[int], act: type[nn.Module] = nn.Softplus) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(act())
    return nn.Sequential(*layers)


class GaussianDecoder(nn.Module):
    HEADS = {"offset": 3, "normal_offset": 3, "color": 3, "scale": 1}

    def __init__(self, in_features: int, hidden: int = 128, trunk_layers: int = 8, skip_layer: int = 4,
                 head_layers: int = 2, init: str = "he") -> None:
        super().__init__()
        self.skip_layer = skip_layer
        self.trunk = nn.ModuleList()
        for i in range(trunk_layers):
            fan_in = in_features if i == 0 else hidden
            if i == skip_layer:
                fan_in += in_features
            self.trunk.append(nn.Linear(fan_in, hidden))
        self.act = nn.Softplus()
        head_sizes = [hidden] + [max(hidden // 2, 8)] * (head_layers - 1)
        self.heads = nn.ModuleDict({name: _mlp(head_sizes + [out]) for name, out in self.HEADS.items()})
        if init == "he":
            # He initialisation (normal, std sqrt(2 / fan_in), as for ReLU: softplus is ReLU-like)
            # keeps the spread of the activations across texels through the trunk. PyTorch's default
            # (std 1/sqrt(3 fan_in)) shrank it ~3x per softplus layer: the colour head's spread
            # across texels was 1e-4 at the start, and trained runs stayed in that state (every texel
            # one offset, one scale) for 300-1350 steps before they left it, at a step that varied
            for lin in (m for m in self.modules() if isinstance(m, nn.Linear)):
                nn.init.kaiming_normal_(lin.weight, nonlinearity="relu")
                nn.init.zeros_(lin.bias)
            # ... but the colour starts about neutral (logits within ~0.01 of 0, as the default
            # init's near-constant output gave; the He trunk's positive activations would start
            # each channel at a random logit, -2 to 1), not at zero, so that the first step's
            # gradients already reach the trunk and the feature map through it
            nn.init.normal_(self.heads["color"][-1].weight, std=1e-3)
        elif init != "torch":
            raise ValueError(f"GaussianDecoder: init must be 'he' or 'torch', found {init!r}")
        # start from the body surface: zero offsets and a neutral colour/scale
        for name in ("offset", "normal_offset"):
            last = self.heads[name][-1]
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)
        nn.init.zeros_(self.heads["scale"][-1].weight)

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        h = x
        for i, layer in enumerate(self.trunk):
            if i == self.skip_layer:
                h = torch.cat([h, x], dim=-1)
            h = self.act(layer(h))
        return {name: head(h) for name, head in self.heads.items()}
