"""One entry for Gaussian splat files of any layout this program knows: the 3DGS ``.ply`` (and
PlayCanvas's compressed ``.ply``), antimatter15's ``.splat``, Niantic's ``.spz`` and PlayCanvas's
SOG (``.sog``, or its ``meta.json`` in a folder to read).

``read_gaussians(path)`` picks the reader by the file's first bytes (``ply`` / gzip or ``NGSP``),
and by its name for ``.splat`` (which has no header) and SOG, and returns ``PlyGaussians`` as
``reconstruct.ply.read_gaussians_ply`` does, with the same checks. Errors are ``PlyFormatError``
naming the file. ``write_gaussians(path, ...)`` writes the layout the name asks for
(``splat_format``), atomically, in the ``up`` frame of ``write_gaussians_ply``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_output
from .ply import (
    MIN_SCALE,
    OPACITY_EPS,
    PlyFormatError,
    PlyGaussians,
    checked_gaussians,
    gaussians_from_columns,
    read_gaussians_ply,
    write_gaussians_ply,
)

GAUSSIAN_SUFFIXES = (".ply", ".splat", ".spz", ".sog")  # a SOG's meta.json is read too
FORMATS = ("ply", "compressed.ply", "splat", "spz", "sog")  # what write_gaussians writes, by file name


def splat_format(path) -> str:
    """The layout a file name asks for: 'compressed.ply' (``NAME.compressed.ply``), 'ply', 'splat',
    'spz' or 'sog'; ValueError for another suffix."""
    name = Path(path).name.lower()
    if name.endswith(".compressed.ply"):
        return "compressed.ply"
    suffix = Path(name).suffix
    if suffix in GAUSSIAN_SUFFIXES:
        return suffix[1:]
    raise ValueError(f"{path}: unsupported splat file type {suffix or '(no suffix)'!r}; supported: .ply, "
                     f".compressed.ply, .splat, .spz, .sog")


def write_gaussians(path, means, scales, rotations, opacities, colors, normals=None, *, up: str = "y_down",
                    sh_degree: int = 3, comments=()) -> Path:
    """Write Gaussians (arrays as ``write_gaussians_ply`` takes them) in the layout ``path`` names:
    the 3DGS ``.ply`` (``sh_degree``, normals, comments), SuperSplat's ``.compressed.ply``
    (comments), ``.splat``, ``.spz`` (version 3, gzip: what every reader takes) or ``.sog``; the last
    four quantise (``docs/ply.md``) and hold no normals and no higher SH. Atomic: a failure leaves the
    previous file or none."""
    fmt = splat_format(path)
    if fmt == "ply":
        return write_gaussians_ply(path, means, scales, rotations, opacities, colors, normals, up=up,
                                   sh_degree=sh_degree, comments=comments)
    means, scales, rotations, opacities, colors, _ = checked_gaussians(means, scales, rotations, opacities,
                                                                       colors, normals, up=up)
    arrays = (means, np.maximum(scales, MIN_SCALE), rotations, np.clip(opacities, OPACITY_EPS, 1.0 - OPACITY_EPS),
              np.clip(colors, 0.0, 1.0))
    if fmt == "compressed.ply":
        from .compressed_ply import encode_compressed_ply

        data = encode_compressed_ply(*arrays, comments=[f"wonderhuman up={up}"] + [str(c) for c in comments])
    elif fmt == "splat":
        from .splat_file import encode_splat

        data = encode_splat(*arrays)
    elif fmt == "sog":
        from .sog import encode_sog

        data = encode_sog(*arrays)
    else:
        from .spz import encode_spz

        data = encode_spz(*arrays, version=3)
    path = Path(path)
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
    return path


def read_gaussians(path) -> PlyGaussians:
    """The Gaussians of a 3DGS or compressed ``.ply``, ``.splat``, ``.spz`` or SOG file (see the
    module docstring); ``PlyFormatError`` naming the file for one that cannot be read."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise PlyFormatError(f"{path}: cannot be read: {exc.strerror or exc}") from exc
    if head.startswith(b"ply\n") or head.startswith(b"ply\r\n"):
        return read_gaussians_ply(path)
    from .sog import decode_sog, is_sog
    from .spz import decode_spz, is_spz

    if is_sog(path, head):
        cols, comments = decode_sog(path)
        return gaussians_from_columns(cols, comments, path)
    data = path.read_bytes()
    if is_spz(data):
        cols, comments = decode_spz(data, path)
        return gaussians_from_columns(cols, comments, path)
    if path.suffix.lower() == ".splat":
        from .splat_file import decode_splat

        return gaussians_from_columns(decode_splat(data, path), (), path)
    if path.suffix.lower() == ".ply":
        return read_gaussians_ply(path)  # names what is wrong with it
    raise PlyFormatError(f"{path}: not a Gaussian splat file this program reads: expected a 3DGS or compressed "
                         f".ply, a .splat, a .spz or a .sog (found {head!r} at its start)")
