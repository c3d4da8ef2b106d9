"""Files dropped on a studio window: a motion file goes to the Pose panel (the avatar performs it),
a splat file to the Beside panel (the viewer: it opens in the File panel).

glfw calls the drop callback while it polls events, on the GL thread; the paths wait in a
``DropQueue`` until the next frame takes them, so a drop never starts work inside glfw's callback.
"""

from __future__ import annotations

from pathlib import Path

from reconstruct.gaussian_files import GAUSSIAN_SUFFIXES as SPLAT_SUFFIXES
from reconstruct.motion.io import MOTION_SUFFIXES


def drop_kind(path) -> str:
    """'motion', 'splat' (a SOG's meta.json too) or 'other', by the file's name."""
    p = Path(str(path))
    if p.name.lower() == "meta.json" or p.suffix.lower() in SPLAT_SUFFIXES:
        return "splat"
    if p.suffix.lower() in MOTION_SUFFIXES:
        return "motion"
    return "other"


def not_taken(path) -> str:
    return (f"{path}: dropped, but neither a motion file ({', '.join(MOTION_SUFFIXES)}) nor a splat file "
            f"({', '.join(SPLAT_SUFFIXES)})")


class DropQueue:
    """Paths dropped since the last frame."""

    def __init__(self) -> None:
        self.paths: list[str] = []

    def install(self, glfw, window) -> None:
        glfw.set_drop_callback(window, lambda _window, paths: self.paths.extend(str(p) for p in paths))

    def take(self) -> list[str]:
        paths, self.paths = self.paths, []
        return paths
