"""antimatter15's ``.splat``: a headerless array of 32-byte records, one per Gaussian.

Each record: position (3 x float32), standard deviations (3 x float32, linear), colour and opacity
(4 x uint8: ``0.5 + C0 f_dc`` and the opacity, times 255), rotation (4 x uint8: the unit quaternion
w, x, y, z mapped from [-1, 1] to [0, 255]). Little endian, in the frame of the 3DGS ``.ply`` it was
converted from. No higher SH. Read as PlayCanvas's ``splat-transform`` reads it and written so
that it reads back (``tests/test_splat_formats.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .ply import C0, PlyFormatError, opacity_logit

RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])


def decode_splat(data: bytes, path: Path) -> dict[str, np.ndarray]:
    """The 3DGS columns of a ``.splat`` file's bytes. Raises ``PlyFormatError`` naming the file."""
    if len(data) == 0 or len(data) % RECORD.itemsize:
        raise PlyFormatError(f"{path}: not a .splat file: its size ({len(data)} bytes) is not a positive multiple of "
                             f"{RECORD.itemsize} (one record per Gaussian)")
    rec = np.frombuffer(data, RECORD)
    out = {}
    for k, axis in enumerate("xyz"):
        out[axis] = rec["position"][:, k].astype(np.float64)
    with np.errstate(divide="ignore"):
        logs = np.log(rec["scale"].astype(np.float64))
    if not np.all(np.isfinite(logs)):
        raise PlyFormatError(f"{path}: {int((~np.isfinite(logs)).any(1).sum())} Gaussians have a scale that is not a "
                             f"positive finite number")
    q = rec["rotation"].astype(np.float64) / 255.0 * 2.0 - 1.0
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    rgba = rec["rgba"].astype(np.float64) / 255.0
    for k in range(3):
        out[f"scale_{k}"] = logs[:, k]
        out[f"f_dc_{k}"] = (rgba[:, k] - 0.5) / C0
    for k in range(4):
        out[f"rot_{k}"] = q[:, k]
    out["opacity"] = opacity_logit(rgba[:, 3])
    return out


def encode_splat(means, scales, rotations, opacities, colors) -> bytes:
    """The ``.splat`` bytes of Gaussians (N,3 means, N,3 standard deviations, N,4 wxyz rotations,
    N opacities, N,3 colours in [0, 1]), in the order given."""
    n = len(means)
    rec = np.zeros(n, RECORD)
    rec["position"] = np.asarray(means, np.float32)
    rec["scale"] = np.asarray(scales, np.float32)
    rgba = np.concatenate([np.asarray(colors, np.float64), np.asarray(opacities, np.float64).reshape(n, 1)], 1)
    rec["rgba"] = np.clip(np.round(rgba * 255.0), 0, 255).astype(np.uint8)
    q = np.asarray(rotations, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    rec["rotation"] = np.clip(np.round((q + 1.0) * 127.5), 0, 255).astype(np.uint8)
    return rec.tobytes()
