"""LPIPS perceptual distance (Zhang et al. 2018, "v0.1") in plain torch, with weight loading.

The network is the official ``lpips`` package's: ScalingLayer -> AlexNet or VGG16 conv features
(torchvision layer layout) tapped after five ReLUs -> unit-normalise each feature vector over
channels -> squared difference -> learned 1x1 "lin" layer (non-negative in the official files)
-> spatial mean -> sum over the five layers. Nothing is downloaded: both weight files are
supplied by path.

Accepted files (all loaded with ``torch.load(..., weights_only=True)``):

- backbone, either
  * a torchvision state dict of ``alexnet`` / ``vgg16`` (e.g. ``alexnet-owt-7be5be79.pth``,
    ``vgg16-397923af.pth``): keys ``features.N.weight`` / ``features.N.bias``; other keys
    (``classifier.*``) are ignored; or
  * a state dict of the official ``lpips.LPIPS`` module (``model.state_dict()``): keys
    ``net.sliceK.N.weight`` / ``.bias`` where ``N`` keeps the torchvision index (alex slices
    [0-1], [2-4], [5-7], [8-9], [10-11]; vgg [0-3], [4-8], [9-15], [16-22], [23-29]).
- lin layers: the official ``weights/v0.1/alex.pth`` / ``vgg.pth``, keys
  ``lin0.model.1.weight`` ... ``lin4.model.1.weight`` of shape ``(1, C_k, 1, 1)``. A full
  ``lpips.LPIPS`` state dict holds the same keys, so it can serve as both files. (A module built
  with ``use_dropout=False`` would name them ``linK.model.0.weight``; that layout is rejected.)
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .psnr import image_pair_as_batch, reduce_per_image

SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
NORM_EPS = 1e-10


@dataclass(frozen=True)
class _Arch:
    """A torchvision ``features`` prefix: ``layers`` specs by index, and the tapped ReLU indices."""

    layers: tuple[tuple, ...]  # ("conv", c_in, c_out, kernel, stride, padding) | ("relu",) | ("pool", k, stride)
    taps: tuple[int, ...]
    torchvision_file: str  # the torchvision release of the ImageNet weights, for error messages

    @property
    def channels(self) -> tuple[int, ...]:
        """Channels of each tapped feature map."""
        return tuple(self._out_channels(i) for i in self.taps)

    def _out_channels(self, index: int) -> int:
        return next(spec[2] for spec in reversed(self.layers[: index + 1]) if spec[0] == "conv")


def _vgg16_layers() -> tuple[tuple, ...]:
    layers: list[tuple] = []
    c_in = 3
    for block, (c_out, n_convs) in enumerate(((64, 2), (128, 2), (256, 3), (512, 3), (512, 3))):
        if block:
            layers.append(("pool", 2, 2))
        for _ in range(n_convs):
            layers += [("conv", c_in, c_out, 3, 1, 1), ("relu",)]
            c_in = c_out
    return tuple(layers)


ARCHS = {
    "alex": _Arch(
        layers=(
            ("conv", 3, 64, 11, 4, 2), ("relu",), ("pool", 3, 2),
            ("conv", 64, 192, 5, 1, 2), ("relu",), ("pool", 3, 2),
            ("conv", 192, 384, 3, 1, 1), ("relu",),
            ("conv", 384, 256, 3, 1, 1), ("relu",),
            ("conv", 256, 256, 3, 1, 1), ("relu",),
        ),
        taps=(1, 4, 7, 9, 11),
        torchvision_file="alexnet-owt-7be5be79.pth",
    ),
    "vgg": _Arch(layers=_vgg16_layers(), taps=(3, 8, 15, 22, 29), torchvision_file="vgg16-397923af.pth"),
}


class LPIPSWeightsError(ValueError):
    """An LPIPS weight file exists but its content is unusable (format, keys or shapes)."""


def _build_layer(spec: tuple) -> nn.Module:
    if spec[0] == "conv":
        _, c_in, c_out, kernel, stride, padding = spec
        return nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=padding)
    if spec[0] == "pool":
        return nn.MaxPool2d(kernel_size=spec[1], stride=spec[2])
    return nn.ReLU()


class LPIPS(nn.Module):
    """LPIPS distance between channels-last RGB images in ``[0, 1]``.

    The constructor builds the architecture with random weights (for tests); for real scores
    use :meth:`from_files` or :func:`load_lpips_or_none`. Parameters are frozen
    (``requires_grad=False``), but the distance is differentiable w.r.t. the images.
    Own state-dict layout: ``features.N.*`` (torchvision indices) and ``lins.K.weight``.
    """

    def __init__(self, net: str = "alex") -> None:
        super().__init__()
        if net not in ARCHS:
            raise ValueError(f"LPIPS: net must be one of {sorted(ARCHS)}, found {net!r}")
        self.net = net
        self.arch = ARCHS[net]
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))
        self.features = nn.Sequential(*(_build_layer(spec) for spec in self.arch.layers))
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in self.arch.channels)
        self.requires_grad_(False)
        self.eval()

    @classmethod
    def from_files(cls, net: str = "alex", *, backbone_path: str | Path, lin_path: str | Path) -> "LPIPS":
        """Build LPIPS for ``net`` ("alex" | "vgg") from a backbone file and a lin-layer file.

        See the module docstring for the accepted key layouts. Raises ``FileNotFoundError`` for a
        missing file and :class:`LPIPSWeightsError` for unusable content.
        """
        model = cls(net)
        backbone = _backbone_state(net, model.arch, Path(backbone_path))
        lins = _lin_state(net, model.arch, Path(lin_path))
        model.load_state_dict({**backbone, **lins, "shift": model.shift, "scale": model.scale})
        return model

    def feature_maps(self, images: torch.Tensor) -> list[torch.Tensor]:
        """The five tapped ReLU outputs ``(B, C_k, h_k, w_k)`` for ``(B, 3, H, W)`` images in [-1, 1]."""
        h = (images - self.shift) / self.scale
        taps = []
        for index, layer in enumerate(self.features):
            h = layer(h)
            if index in self.arch.taps:
                taps.append(h)
        return taps

    def forward(self, pred: torch.Tensor, target: torch.Tensor, *, reduction: str = "mean") -> torch.Tensor:
        """LPIPS of ``(H, W, 3)`` or ``(B, H, W, 3)`` images in [0, 1] (mapped to [-1, 1] here).

        Inputs are cast to the parameters' dtype. ``reduction``: ``"mean"`` -> scalar,
        ``"none"`` -> ``(B,)`` (a scalar for an unbatched input). Needs H, W >= 31 (alex), 16 (vgg).
        """
        pred, target, batched = image_pair_as_batch(pred, target, "lpips")
        if pred.shape[-1] != 3:
            raise ValueError(f"lpips: expected RGB images (C = 3), found shape {tuple(pred.shape)}")
        dtype = self.shift.dtype
        both = torch.cat([pred, target]).permute(0, 3, 1, 2).to(dtype) * 2 - 1
        distance = both.new_zeros(pred.shape[0])
        for feats, lin in zip(self.feature_maps(both), self.lins):
            unit = feats / (feats.square().sum(dim=1, keepdim=True).sqrt() + NORM_EPS)
            f0, f1 = unit.chunk(2)
            distance = distance + lin((f0 - f1).square()).mean(dim=(1, 2, 3))
        return reduce_per_image(distance, reduction, batched, "lpips")


# ----- weight files -------------------------------------------------------------------------

_LIN_KEY = "lin{k}.model.1.weight"
_LPIPS_BACKBONE_KEY = re.compile(r"^net\.slice[1-5]\.(\d+)\.(weight|bias)$")


def _read_state_dict(path: Path, role: str, expected: str) -> Mapping[str, Any]:
    """``torch.load`` a state dict, with errors that name the file, its role and what it should be."""
    if not path.is_file():
        raise FileNotFoundError(f"LPIPS {role} file not found: {path} (expected {expected})")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch.load raises many types (UnpicklingError, RuntimeError, EOFError...)
        raise LPIPSWeightsError(
            f"LPIPS {role} file {path} is not a readable torch state dict "
            f"(torch.load failed: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
        ) from exc
    if not isinstance(state, Mapping) or not all(isinstance(k, str) for k in state):
        raise LPIPSWeightsError(
            f"LPIPS {role} file {path} is not a torch state dict: expected a mapping from parameter "
            f"names to tensors, found {type(state).__name__}"
        )
    return state


def _take(
    state: Mapping[str, Any], wanted: dict[str, tuple[str, tuple[int, ...]]], role: str, path: Path
) -> dict[str, torch.Tensor]:
    """Pick ``wanted`` (file key -> (our key, expected shape)) from ``state``, checking keys and shapes."""
    missing = [key for key in wanted if key not in state]
    if missing:
        raise LPIPSWeightsError(
            f"LPIPS {role} file {path} is missing {len(missing)} of {len(wanted)} expected keys, "
            f"e.g. {missing[:4]}; keys found include {list(state)[:4]}"
        )
    out, wrong = {}, []
    for key, (ours, shape) in wanted.items():
        value = state[key]
        found = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__
        if found != shape:
            wrong.append(f"{key}: expected {shape}, found {found}")
        else:
            out[ours] = value
    if wrong:
        raise LPIPSWeightsError(f"LPIPS {role} file {path} has wrong shapes: " + "; ".join(wrong[:4]))
    return out


def _backbone_state(net: str, arch: _Arch, path: Path) -> dict[str, torch.Tensor]:
    role = f"{net} backbone"
    expected = (
        f"a torchvision state dict such as {arch.torchvision_file} (features.N.weight) "
        f"or an lpips.LPIPS(net={net!r}) state dict (net.sliceK.N.weight)"
    )
    state = _read_state_dict(path, role, expected)
    if any(key.startswith("features.") for key in state):
        lpips_layout = False
    elif any(_LPIPS_BACKBONE_KEY.match(key) for key in state):
        lpips_layout = True
    else:
        raise LPIPSWeightsError(
            f"LPIPS {role} file {path} has neither torchvision keys (features.N.weight) nor lpips keys "
            f"(net.sliceK.N.weight); keys found include {list(state)[:4]}"
        )
    wanted = {}
    for i, spec in enumerate(arch.layers):
        if spec[0] == "conv":
            _, c_in, c_out, kernel, _, _ = spec
            source = f"net.slice{_slice_of(arch, i)}.{i}" if lpips_layout else f"features.{i}"
            wanted[source + ".weight"] = (f"features.{i}.weight", (c_out, c_in, kernel, kernel))
            wanted[source + ".bias"] = (f"features.{i}.bias", (c_out,))
    return _take(state, wanted, role, path)


def _slice_of(arch: _Arch, index: int) -> int:
    """The lpips ``sliceK`` (1-based) holding torchvision layer ``index``: slices end at the taps."""
    return next(k for k, tap in enumerate(arch.taps, start=1) if index <= tap)


def _lin_state(net: str, arch: _Arch, path: Path) -> dict[str, torch.Tensor]:
    role = f"{net} lin-layer"
    expected = f"the official lpips weights/v0.1/{net}.pth with keys lin0.model.1.weight ... lin4.model.1.weight"
    state = _read_state_dict(path, role, expected)
    wanted = {_LIN_KEY.format(k=k): (f"lins.{k}.weight", (1, c, 1, 1)) for k, c in enumerate(arch.channels)}
    return _take(state, wanted, role, path)


# ----- optional loading -----------------------------------------------------------------------


@dataclass(frozen=True)
class LPIPSConfig:
    """Where the LPIPS weights live; both paths unset means LPIPS is off."""

    net: str = "alex"
    backbone_path: str | Path | None = None
    lin_path: str | Path | None = None


def load_lpips_or_none(config: LPIPSConfig | Mapping[str, Any] | None) -> tuple[LPIPS | None, str]:
    """Load LPIPS if it is configured and its files are usable; never raises for missing weights.

    ``config``: an :class:`LPIPSConfig`, a mapping with the same keys, or None. Returns
    ``(model, "LPIPS (<net>) loaded from ...")`` or ``(None, reason)`` where ``reason`` says why
    LPIPS is unavailable (not configured, a path missing, or the loading error's message). The
    caller must report the reason instead of an LPIPS value.
    """
    if config is None:
        config = LPIPSConfig()
    elif isinstance(config, Mapping):
        unknown = set(config) - {"net", "backbone_path", "lin_path"}
        if unknown:
            return None, f"LPIPS unavailable: unknown config keys {sorted(unknown)}"
        config = LPIPSConfig(**config)
    if config.backbone_path is None and config.lin_path is None:
        return None, "LPIPS unavailable: no weights configured (set backbone_path and lin_path)"
    if config.backbone_path is None or config.lin_path is None:
        unset = "backbone_path" if config.backbone_path is None else "lin_path"
        return None, f"LPIPS unavailable: {unset} is not set (both backbone_path and lin_path are required)"
    try:
        model = LPIPS.from_files(config.net, backbone_path=config.backbone_path, lin_path=config.lin_path)
    except (FileNotFoundError, ValueError) as exc:  # LPIPSWeightsError is a ValueError, as is a bad net
        return None, f"LPIPS unavailable: {exc}"
    return model, f"LPIPS ({config.net}) loaded from {config.backbone_path} and {config.lin_path}"
