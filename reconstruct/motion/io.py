"""One entry for reading any supported motion file."""

from __future__ import annotations

import os
from pathlib import Path

from .clip import MotionClip, MotionFileError

MOTION_SUFFIXES = (".bvh", ".npz", ".glb", ".gltf", ".fbx")


def load_motion(path: str | os.PathLike, *, up: str | None = None, forward: str | None = None,
                metres_per_unit: float | None = None) -> MotionClip:
    """Reads a motion file by its suffix: ``.bvh`` (BVH), ``.glb`` / ``.gltf`` (a glTF 2.0 skin's
    animation), ``.fbx`` (binary FBX: a skeleton's first animation stack) or ``.npz`` (SMPL / SMPL-H / SMPL-X sequence). ``up``/``forward`` ("+Y", "-Z", ...)
    and ``metres_per_unit`` override what is detected from a BVH, glTF or FBX skeleton. Raises ``MotionFileError`` naming the file (and line)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if not path.is_file():
        raise MotionFileError(f"{path}: no such motion file")
    if suffix == ".bvh":
        from .bvh import read_bvh

        return read_bvh(path, up=up, forward=forward, metres_per_unit=metres_per_unit)
    if suffix in (".glb", ".gltf"):
        from .gltf import read_gltf

        return read_gltf(path, up=up, forward=forward, metres_per_unit=metres_per_unit)
    if suffix == ".fbx":
        from .fbx import read_fbx

        return read_fbx(path, up=up, forward=forward, metres_per_unit=metres_per_unit)
    if suffix == ".npz":
        if up or forward or metres_per_unit:
            raise MotionFileError(f"{path}: up/forward/metres_per_unit apply to BVH, glTF and FBX files only")
        from .smpl_npz import read_smpl_npz

        return read_smpl_npz(path)
    if suffix in (".pkl", ".pickle"):
        raise MotionFileError(f"{path}: pickle files are refused (they can run code when loaded); "
                              f"save the SMPL arrays as an .npz with numpy.savez")
    raise MotionFileError(f"{path}: unsupported motion file type {suffix or '(none)'!r}; "
                          f"supported: {', '.join(MOTION_SUFFIXES)}")
