"""Loaders for real datasets: each turns a dataset folder into the same ``Scene``.

Spec syntax (see docs/loaders.md):

    zju:PATH[,key=value...]        ZJU-MoCap, Instant-NVR layout
    monocap:PATH[,...]             MonoCap (and original ZJU-MoCap CoreView folders)
    snapshot:PATH[,...]            PeopleSnapshot as processed by InstantAvatar
    gaussian_avatar:PATH[,...]     the GaussianAvatar layout
    auto:PATH[,...] or a bare PATH the layout detected from the folder

keys: train_camera=NAME|INDEX, frames=START:STOP[:STEP], eval_cameras=N|A+B+..., eval_every=K,
scale=F, gender=neutral|female|male, smpl_dir=FOLDER.
"""

from __future__ import annotations

from pathlib import Path

from ..scene import Scene
from .common import LoaderError, Protocol, parse_options
from .detect import ALIASES, LAYOUTS, detect_layout, requirements

__all__ = ["LoaderError", "Protocol", "detect_layout", "is_loader_spec", "load_dataset", "parse_spec", "requirements"]


def is_loader_spec(spec: str) -> bool:
    head = spec.split(":", 1)[0].lower()
    return ":" in spec and (head in ALIASES or head == "auto")


def parse_spec(spec: str) -> tuple[str | None, Path, Protocol]:
    """``layout:PATH,key=value,...`` (or a bare PATH) -> (layout or None for auto, folder, protocol)."""
    layout = None
    body = spec
    if is_loader_spec(spec):
        head, body = spec.split(":", 1)
        layout = None if head.lower() == "auto" else ALIASES[head.lower()]
    parts = body.split(",")
    # a comma inside the path: keep joining until the next item looks like key=value
    path, rest = parts[0], parts[1:]
    while rest and "=" not in rest[0]:
        path += "," + rest.pop(0)
    if not path.strip():
        raise ValueError(f"scene {spec!r}: no folder given")
    return layout, Path(path.strip()).expanduser(), parse_options(spec, rest)


def load_dataset(spec: str | Path, protocol: Protocol | None = None) -> Scene:
    """A Scene from a dataset spec or folder (layout detected when not named)."""
    layout, folder, parsed = parse_spec(str(spec))
    protocol = protocol or parsed
    if not folder.is_dir():
        raise LoaderError(f"{folder}: no such folder")
    name = layout or detect_layout(folder)
    return LAYOUTS[name].load(folder, protocol)
