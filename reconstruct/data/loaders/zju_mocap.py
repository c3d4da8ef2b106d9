"""ZJU-MoCap as refined and laid out by Instant-NVR (``my_377`` ...): ``annots.npy``,
``images/<cam>/``, ``mask/<cam>/`` and EasyMocap SMPL parameters in ``smpl_params/<n>.npy``.
See ``annots_layout`` for the format and conventions."""

from __future__ import annotations

from pathlib import Path

from ..scene import Scene
from .annots_layout import load_annots_layout
from .common import Protocol

NAME = "zju"
PARAMS_DIR = "smpl_params"
NEEDS = "annots.npy, smpl_params/<n>.npy, images/<cam>/ and mask/<cam>/"


def matches(folder: Path) -> bool:
    return (folder / "annots.npy").is_file() and (folder / PARAMS_DIR).is_dir()


def load(folder: str | Path, protocol: Protocol | None = None) -> Scene:
    return load_annots_layout(Path(folder), protocol or Protocol(), PARAMS_DIR, NAME)
