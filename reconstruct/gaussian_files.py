"""One entry for reading Gaussian splat files of any layout this program knows: the 3DGS ``.ply``
(and PlayCanvas's compressed ``.ply``), antimatter15's ``.splat`` and Niantic's ``.spz``.

``read_gaussians(path)`` picks the reader by the file's first bytes (``ply`` / gzip or ``NGSP``),
and by its suffix for ``.splat`` (which has no header), and returns ``PlyGaussians`` as
``reconstruct.ply.read_gaussians_ply`` does, with the same checks. Errors are ``PlyFormatError``
naming the file.
"""

from __future__ import annotations

from pathlib import Path

from .ply import PlyFormatError, PlyGaussians, gaussians_from_columns, read_gaussians_ply

GAUSSIAN_SUFFIXES = (".ply", ".splat", ".spz")


def read_gaussians(path) -> PlyGaussians:
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise PlyFormatError(f"{path}: cannot be read: {exc.strerror or exc}") from exc
    if head.startswith(b"ply\n") or head.startswith(b"ply\r\n"):
        return read_gaussians_ply(path)
    from .spz import decode_spz, is_spz

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
                         f".ply, a .splat or a .spz (found {head!r} at its start)")
