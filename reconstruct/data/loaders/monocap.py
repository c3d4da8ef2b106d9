"""MonoCap (DeepCap/DynaCap subjects as processed by AnimatableNeRF, used by Instant-NVR), and the
original ZJU-MoCap ``CoreView_*`` folders, which share its layout: ``annots.npy``,
``images/<cam>/`` (or ``Camera_*/``), ``mask/<cam>/`` and EasyMocap SMPL parameters in
``params/<n>.npy``, where n is the frame number in the image's name (1-based for some subjects).
See ``annots_layout`` for the format and conventions."""

from __future__ import annotations

from pathlib import Path

from ..scene import Scene
from .annots_layout import load_annots_layout
from .common import Protocol

NAME = "monocap"
PARAMS_DIR = "params"
NEEDS = "annots.npy, params/<n>.npy, images/<cam>/ and mask/<cam>/"


def matches(folder: Path) -> bool:
    return (folder / "annots.npy").is_file() and (folder / PARAMS_DIR).is_dir()


def load(folder: str | Path, protocol: Protocol | None = None) -> Scene:
    return load_annots_layout(Path(folder), protocol or Protocol(), PARAMS_DIR, NAME)
