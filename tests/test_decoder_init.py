"""The decoder's initialisation: its outputs differ from texel to texel from the first step (He),
where PyTorch's default Linear init gave every texel the same output; the offset and normal heads
still start at zero (the Gaussians on the body surface)."""

import pytest
import torch

from reconstruct.avatar.config import AvatarConfig
from reconstruct.avatar.decoder import GaussianDecoder
from reconstruct.avatar.model import AvatarModel
from reconstruct.train.config import Stage1Config


def _inputs(n: int, channels: int) -> torch.Tensor:
    """Decoder inputs as at the start of training: [S, S] from a feature map of std 0.01, and the
    texels' UV coordinates in [-1, 1]."""
    g = torch.Generator().manual_seed(1)
    s = torch.randn(n, channels, generator=g) * 0.01
    return torch.cat([s, s, torch.rand(n, 2, generator=g) * 2 - 1], 1)


def _trunk_spread(d: GaussianDecoder, x: torch.Tensor) -> list[float]:
    """Mean over units of each trunk layer's activation std across texels."""
    out, h = [], x
    with torch.no_grad():
        for i, layer in enumerate(d.trunk):
            if i == d.skip_layer:
                h = torch.cat([h, x], -1)
            h = d.act(layer(h))
            out.append(float(h.std(0).mean()))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_he_init_keeps_the_texels_apart_through_the_trunk_and_torch_init_does_not(seed):
    x = _inputs(3000, 64)
    torch.manual_seed(seed)
    he = GaussianDecoder(x.shape[1], init="he")
    torch.manual_seed(seed)
    default = GaussianDecoder(x.shape[1], init="torch")
    he_spread, default_spread = _trunk_spread(he, x), _trunk_spread(default, x)
    assert he_spread[-1] > 0.2 * he_spread[0]
    assert default_spread[-1] < 0.05 * default_spread[0]  # what the He init is for
    with torch.no_grad():
        start = he(x)["color"]
    assert float(start.abs().max()) < 0.05  # about neutral everywhere at the start


def _fit_colour(d: GaussianDecoder, x: torch.Tensor, target: torch.Tensor, steps: int) -> float:
    opt = torch.optim.Adam(d.parameters(), lr=3e-3)  # the decoder's Stage I rate
    for _ in range(steps):
        loss = ((torch.sigmoid(d(x)["color"]) - target) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return float(loss.detach())


def test_he_init_learns_a_colour_that_differs_across_texels_in_a_few_steps():
    x = _inputs(500, 16)
    u, v = x[:, -2], x[:, -1]
    target = torch.stack([(u > 0).float(), (v > 0).float(), 0.5 * torch.ones_like(u)], 1)  # four quadrants
    base = float(((0.5 - target) ** 2).mean())
    losses = {}
    for init in ("he", "torch"):
        torch.manual_seed(0)
        losses[init] = _fit_colour(GaussianDecoder(x.shape[1], hidden=32, init=init), x, target, 80)
    # measured: 0.010 (He) and 0.103 (PyTorch's default) against 0.167 for the neutral colour
    assert losses["he"] < 0.3 * base
    assert losses["he"] < 0.3 * losses["torch"]


def test_offset_and_normal_heads_start_at_zero_with_either_init():
    x = _inputs(500, 16)
    for init in ("he", "torch"):
        out = GaussianDecoder(x.shape[1], hidden=32, init=init)(x)
        assert torch.count_nonzero(out["offset"]) == 0 and torch.count_nonzero(out["normal_offset"]) == 0
    with pytest.raises(ValueError, match="init"):
        GaussianDecoder(x.shape[1], init="xavier")


def test_the_config_chooses_the_init_and_old_records_keep_the_default_one(monkeypatch, anny_body):
    seen = []
    real = GaussianDecoder.__init__

    def spy(self, *a, init="he", **kw):
        seen.append(init)
        real(self, *a, init=init, **kw)

    monkeypatch.setattr(GaussianDecoder, "__init__", spy)
    small = dict(gaussian_resolution=32, feature_resolution=16, feature_channels=4, pose_feature_channels=4, hidden=16)
    AvatarModel(anny_body, AvatarConfig(**small))
    AvatarModel(anny_body, AvatarConfig.paper(**small))
    assert seen == ["he", "torch"]
    assert AvatarConfig().decoder_init == "he"
    rec = Stage1Config().to_dict()
    del rec["avatar"]["decoder_init"]
    assert Stage1Config.from_dict(rec).avatar.decoder_init == "torch"
    with pytest.raises(ValueError, match="decoder_init"):
        AvatarConfig(decoder_init="zeros")
