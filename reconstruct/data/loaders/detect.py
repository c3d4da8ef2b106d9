"""Which dataset layout a folder is in."""

from __future__ import annotations

from pathlib import Path

from . import gaussian_avatar, monocap, people_snapshot, zju_mocap
from .common import LoaderError

LAYOUTS = {m.NAME: m for m in (zju_mocap, monocap, people_snapshot, gaussian_avatar)}
ALIASES = {"zju": "zju", "zju_mocap": "zju", "zjumocap": "zju", "monocap": "monocap", "snapshot": "snapshot",
           "peoplesnapshot": "snapshot", "people_snapshot": "snapshot", "gaussian_avatar": "gaussian_avatar",
           "gaussianavatar": "gaussian_avatar", "gsavatar": "gaussian_avatar"}


def requirements() -> str:
    lines = ["  scene folder (this program's own): scene.json, poses.npz, frames/ (docs/scene_format.md)"]
    lines += [f"  {name}: {m.NEEDS}" for name, m in LAYOUTS.items()]
    return "\n".join(lines)


def detect_layout(folder: str | Path) -> str:
    """The layout name of ``folder``; LoaderError naming what each layout needs when none matches."""
    folder = Path(folder)
    if not folder.is_dir():
        raise LoaderError(f"{folder}: no such folder")
    for name, module in LAYOUTS.items():
        if module.matches(folder):
            return name
    params = [d for d in ("smpl_params", "params") if (folder / d).is_dir()]
    if params and not (folder / "annots.npy").is_file():
        raise LoaderError(f"{folder / 'annots.npy'}: missing; the folder has {params[0]}/ like a ZJU-MoCap/MonoCap "
                          f"folder, which also needs annots.npy (a dict with 'cams' {{K, D, R, T}} and per-frame 'ims')")
    found = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir())
    raise LoaderError(f"{folder}: unknown dataset layout; found {found[:12]}{' ...' if len(found) > 12 else ''}. "
                      f"Known layouts and what each needs:\n{requirements()}")
