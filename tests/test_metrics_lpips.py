"""LPIPS: weight layouts, loading errors, and the distance against an independent reference.

Real weights cannot be downloaded here, so random weights of the exact architectures are saved
in the accepted layouts (key tables written out below from torchvision / lpips, independently
of the module's own layer specs) and loaded through ``LPIPS.from_files``.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from reconstruct.metrics import LPIPS, LPIPSConfig, load_lpips_or_none
from reconstruct.metrics.lpips import LPIPSWeightsError

# torchvision alexnet().features: index -> (out, in, kernel, stride, padding); max-pools 3/2 at 2, 5, 12.
ALEX_CONVS = {
    0: (64, 3, 11, 4, 2), 3: (192, 64, 5, 1, 2), 6: (384, 192, 3, 1, 1), 8: (256, 384, 3, 1, 1), 10: (256, 256, 3, 1, 1)
}
ALEX_POOL_AFTER_CONV = {0, 3}  # a 3/2 max-pool follows these convs' ReLUs (features.2 and .5)
ALEX_SLICES = {0: 1, 3: 2, 6: 3, 8: 4, 10: 5}  # lpips pretrained_networks.alexnet: conv index -> sliceK
# torchvision vgg16().features: convs (3x3, pad 1) at these indices; 2x2 max-pools at 4, 9, 16, 23.
VGG_CONVS = {0: (64, 3), 2: (64, 64), 5: (128, 64), 7: (128, 128), 10: (256, 128), 12: (256, 256), 14: (256, 256),
             17: (512, 256), 19: (512, 512), 21: (512, 512), 24: (512, 512), 26: (512, 512), 28: (512, 512)}
VGG_POOLS_AT = {4, 9, 16, 23}
VGG_TAPS = (3, 8, 15, 22, 29)
LIN_CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}


def random_torchvision_state(net: str, seed: int = 0) -> dict[str, torch.Tensor]:
    """A torchvision-format ``features`` state dict (plus an unused classifier key)."""
    gen = torch.Generator().manual_seed(seed)
    state = {}
    if net == "alex":
        shapes = {i: (o, c, k, k) for i, (o, c, k, _, _) in ALEX_CONVS.items()}
    else:
        shapes = {i: (o, c, 3, 3) for i, (o, c) in VGG_CONVS.items()}
    for i, shape in shapes.items():
        fan_in = shape[1] * shape[2] * shape[3]
        state[f"features.{i}.weight"] = torch.randn(shape, generator=gen) * (2.0 / fan_in) ** 0.5
        state[f"features.{i}.bias"] = 0.01 * torch.randn(shape[0], generator=gen)
    state["classifier.1.weight"] = torch.zeros(4, 4)
    return state


def random_lin_state(net: str, seed: int = 1) -> dict[str, torch.Tensor]:
    """Official v0.1 lin-layer layout: non-negative ``linK.model.1.weight`` of shape (1, C, 1, 1)."""
    gen = torch.Generator().manual_seed(seed)
    return {
        f"lin{k}.model.1.weight": torch.rand((1, c, 1, 1), generator=gen) / c for k, c in enumerate(LIN_CHANNELS[net])
    }


def lpips_module_state(backbone: dict[str, torch.Tensor], lins: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """What ``lpips.LPIPS(net='alex').state_dict()`` holds: scaling buffers, net.sliceK.N, linK and lins.K."""
    state = {"scaling_layer.shift": torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1),
             "scaling_layer.scale": torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1)}
    for key, value in backbone.items():
        match = re.fullmatch(r"features\.(\d+)\.(weight|bias)", key)
        if match:
            index = int(match[1])
            state[f"net.slice{ALEX_SLICES[index]}.{index}.{match[2]}"] = value
    for key, value in lins.items():
        state[key] = value
        state[key.replace("lin", "lins.", 1)] = value
    return state


@pytest.fixture(scope="module")
def alex_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("lpips_alex")
    backbone, lins = random_torchvision_state("alex"), random_lin_state("alex")
    paths = {"backbone": root / "alexnet-owt.pth", "lin": root / "alex.pth", "combined": root / "lpips_alex_full.pth"}
    torch.save(backbone, paths["backbone"])
    torch.save(lins, paths["lin"])
    torch.save(lpips_module_state(backbone, lins), paths["combined"])
    return paths, backbone, lins


@pytest.fixture(scope="module")
def alex(alex_files):
    paths, _, _ = alex_files
    return LPIPS.from_files("alex", backbone_path=paths["backbone"], lin_path=paths["lin"])


def image_pair(size: int = 64, seed: int = 0, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    a = torch.rand((2, size, size, 3), generator=gen, dtype=dtype)
    b = (a + 0.2 * torch.randn(a.shape, generator=gen, dtype=dtype)).clamp(0, 1)
    return a, b


def reference_alex_features(state: dict[str, torch.Tensor], x: torch.Tensor) -> list[torch.Tensor]:
    """AlexNet taps with functional ops straight from the torchvision state dict, (B, 3, H, W) in [-1, 1]."""
    shift = torch.tensor([-0.030, -0.088, -0.188], dtype=x.dtype).view(1, 3, 1, 1)
    scale = torch.tensor([0.458, 0.448, 0.450], dtype=x.dtype).view(1, 3, 1, 1)
    h, taps = (x - shift) / scale, []
    for i, (_, _, _, stride, padding) in ALEX_CONVS.items():
        w, b = state[f"features.{i}.weight"].to(x.dtype), state[f"features.{i}.bias"].to(x.dtype)
        h = F.relu(F.conv2d(h, w, b, stride=stride, padding=padding))
        taps.append(h)
        if i in ALEX_POOL_AFTER_CONV:
            h = F.max_pool2d(h, 3, 2)
    return taps


def reference_distance(feats0: list[np.ndarray], feats1: list[np.ndarray], lins: list[np.ndarray]) -> np.ndarray:
    """Zhang et al. eq. 1 in float64 numpy: sum_l mean_hw || w_l * (unit(f0) - unit(f1)) ||^2."""
    total = np.zeros(feats0[0].shape[0])
    for f0, f1, w in zip(feats0, feats1, lins):
        u0 = f0 / (np.sqrt((f0**2).sum(axis=1, keepdims=True)) + 1e-10)
        u1 = f1 / (np.sqrt((f1**2).sum(axis=1, keepdims=True)) + 1e-10)
        total += np.einsum("bchw,c->bhw", (u0 - u1) ** 2, w.reshape(-1)).mean(axis=(1, 2))
    return total


def test_alex_features_match_functional_reference(alex, alex_files):
    _, backbone, _ = alex_files
    x = torch.rand(2, 3, 64, 64) * 2 - 1
    ours = alex.feature_maps(x)
    ref = reference_alex_features(backbone, x)
    assert [tuple(f.shape[1:]) for f in ours] == [(64, 15, 15), (192, 7, 7), (384, 3, 3), (256, 3, 3), (256, 3, 3)]
    for a, b in zip(ours, ref):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)


def test_alex_distance_matches_numpy_reference(alex_files):
    paths, backbone, lins = alex_files
    model = LPIPS.from_files("alex", backbone_path=paths["backbone"], lin_path=paths["lin"]).double()
    a, b = image_pair(dtype=torch.float64)
    feats = [reference_alex_features(backbone, img.permute(0, 3, 1, 2) * 2 - 1) for img in (a, b)]
    expected = reference_distance(
        [f.numpy() for f in feats[0]], [f.numpy() for f in feats[1]], [w.double().numpy() for w in lins.values()]
    )
    # Not 1e-12: the module keeps lpips' float32 shift/scale constants, the reference float64 ones.
    np.testing.assert_allclose(model(a, b, reduction="none").numpy(), expected, rtol=1e-7)


def test_combined_lpips_layout_loads_identically(alex, alex_files):
    paths, _, _ = alex_files
    combined = LPIPS.from_files("alex", backbone_path=paths["combined"], lin_path=paths["combined"])
    a, b = image_pair()
    assert torch.equal(combined(a, b, reduction="none"), alex(a, b, reduction="none"))


def test_distance_properties(alex):
    a, b = image_pair()
    d = alex(a, b, reduction="none")
    assert d.shape == (2,) and torch.isfinite(d).all() and (d > 0).all()
    assert torch.equal(alex(a, b, reduction="none"), d)
    assert alex(a, a).item() == 0.0
    assert alex(a[0], b[0]).item() == pytest.approx(d[0].item(), rel=1e-5)
    assert alex(a, b).item() == pytest.approx(d.mean().item(), rel=1e-6)

    pred = b.clone().requires_grad_(True)
    alex(pred, a).backward()
    assert torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0
    assert all(p.grad is None for p in alex.parameters())


def test_vgg_loads_and_matches_numpy_reference(tmp_path):
    backbone, lins = random_torchvision_state("vgg"), random_lin_state("vgg")
    torch.save(backbone, tmp_path / "vgg16.pth")
    torch.save(lins, tmp_path / "vgg.pth")
    model = LPIPS.from_files("vgg", backbone_path=tmp_path / "vgg16.pth", lin_path=tmp_path / "vgg.pth")
    a, b = image_pair(size=32)
    d = model(a, b, reduction="none")
    assert torch.isfinite(d).all() and (d > 0).all() and model(a, a).item() == 0.0

    # Independent functional VGG16 from the key table, then the numpy distance.
    def taps(img):
        h = (img.permute(0, 3, 1, 2) * 2 - 1 - model.shift) / model.scale
        out = []
        for i in range(30):
            if i in VGG_CONVS:
                h = F.conv2d(h, backbone[f"features.{i}.weight"], backbone[f"features.{i}.bias"], padding=1)
            elif i in VGG_POOLS_AT:
                h = F.max_pool2d(h, 2, 2)
            else:
                h = F.relu(h)
            if i in VGG_TAPS:
                out.append(h.double().numpy())
        return out

    with torch.no_grad():
        expected = reference_distance(taps(a), taps(b), [w.double().numpy() for w in lins.values()])
    np.testing.assert_allclose(d.numpy(), expected, rtol=1e-4)


# ----- errors -----------------------------------------------------------------------------------


def test_missing_files_name_path_and_expected_file(alex_files, tmp_path):
    paths, _, _ = alex_files
    missing = tmp_path / "nowhere" / "alexnet.pth"
    with pytest.raises(FileNotFoundError, match=r"alex backbone file not found: .*nowhere.*alexnet-owt-7be5be79\.pth"):
        LPIPS.from_files("alex", backbone_path=missing, lin_path=paths["lin"])
    with pytest.raises(FileNotFoundError, match=r"alex lin-layer file not found: .*nowhere.*weights/v0\.1/alex\.pth"):
        LPIPS.from_files("alex", backbone_path=paths["backbone"], lin_path=missing)


def test_not_a_state_dict(alex_files, tmp_path):
    paths, _, _ = alex_files
    garbage = tmp_path / "garbage.pth"
    garbage.write_bytes(b"this is not a checkpoint")
    message = "garbage.pth is not a readable torch state dict (torch.load failed"
    with pytest.raises(LPIPSWeightsError, match=re.escape(message)):
        LPIPS.from_files("alex", backbone_path=garbage, lin_path=paths["lin"])
    tensor_file = tmp_path / "tensor.pth"
    torch.save(torch.zeros(3), tensor_file)
    with pytest.raises(LPIPSWeightsError, match="is not a torch state dict: expected a mapping .* found Tensor"):
        LPIPS.from_files("alex", backbone_path=paths["backbone"], lin_path=tensor_file)


def test_missing_keys_are_listed(alex_files, tmp_path):
    paths, backbone, lins = alex_files
    partial = {k: v for k, v in backbone.items() if not k.startswith("features.8.")}
    torch.save(partial, tmp_path / "partial.pth")
    message = "missing 2 of 10 expected keys, e.g. ['features.8.weight', 'features.8.bias']"
    with pytest.raises(LPIPSWeightsError, match=re.escape(message)):
        LPIPS.from_files("alex", backbone_path=tmp_path / "partial.pth", lin_path=paths["lin"])
    torch.save({k: v for k, v in lins.items() if not k.startswith("lin4")}, tmp_path / "lins.pth")
    message = r"alex lin-layer file .* missing 1 of 5 expected keys, e\.g\. \['lin4\.model\.1\.weight'\]"
    with pytest.raises(LPIPSWeightsError, match=message):
        LPIPS.from_files("alex", backbone_path=paths["backbone"], lin_path=tmp_path / "lins.pth")
    torch.save({"conv1.weight": torch.zeros(1)}, tmp_path / "other.pth")
    with pytest.raises(LPIPSWeightsError, match=r"neither torchvision keys .* keys found include \['conv1\.weight'\]"):
        LPIPS.from_files("alex", backbone_path=tmp_path / "other.pth", lin_path=paths["lin"])


def test_wrong_shapes_name_key_expected_and_found(alex_files, tmp_path):
    paths, backbone, lins = alex_files
    torch.save({**backbone, "features.0.weight": torch.zeros(64, 3, 7, 7)}, tmp_path / "bad.pth")
    message = "features.0.weight: expected (64, 3, 11, 11), found (64, 3, 7, 7)"
    with pytest.raises(LPIPSWeightsError, match=re.escape(message)):
        LPIPS.from_files("alex", backbone_path=tmp_path / "bad.pth", lin_path=paths["lin"])
    torch.save({**lins, "lin0.model.1.weight": torch.zeros(1, 64, 1, 1, 1)}, tmp_path / "bad_lin.pth")
    message = "lin0.model.1.weight: expected (1, 64, 1, 1), found (1, 64, 1, 1, 1)"
    with pytest.raises(LPIPSWeightsError, match=re.escape(message)):
        LPIPS.from_files("alex", backbone_path=paths["backbone"], lin_path=tmp_path / "bad_lin.pth")


def test_lin_file_of_the_other_net_is_rejected(alex_files, tmp_path):
    paths, _, _ = alex_files
    torch.save(random_lin_state("vgg"), tmp_path / "vgg.pth")
    message = "lin1.model.1.weight: expected (1, 192, 1, 1), found (1, 128, 1, 1)"
    with pytest.raises(LPIPSWeightsError, match=re.escape(message)):
        LPIPS.from_files("alex", backbone_path=paths["backbone"], lin_path=tmp_path / "vgg.pth")


def test_bad_inputs(alex):
    with pytest.raises(ValueError, match="net must be one of"):
        LPIPS("squeeze")
    with pytest.raises(ValueError, match=r"expected RGB images \(C = 3\)"):
        alex(torch.rand(64, 64, 1), torch.rand(64, 64, 1))


# ----- optional loading ---------------------------------------------------------------------------


def test_load_lpips_or_none(alex_files, alex, tmp_path):
    paths, _, _ = alex_files
    model, reason = load_lpips_or_none(None)
    assert model is None and "no weights configured" in reason
    model, reason = load_lpips_or_none({"backbone_path": paths["backbone"]})
    assert model is None and "lin_path is not set" in reason
    config = {"net": "alex", "backbone_path": tmp_path / "absent.pth", "lin_path": paths["lin"]}
    model, reason = load_lpips_or_none(config)
    assert model is None and "file not found" in reason and "absent.pth" in reason
    model, reason = load_lpips_or_none({"backbone_path": paths["backbone"], "lin": paths["lin"]})
    assert model is None and "unknown config keys ['lin']" in reason

    model, reason = load_lpips_or_none(LPIPSConfig("alex", paths["backbone"], paths["lin"]))
    assert isinstance(model, LPIPS) and "loaded" in reason
    a, b = image_pair()
    assert torch.equal(model(a, b), alex(a, b))
