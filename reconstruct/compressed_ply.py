"""PlayCanvas / SuperSplat's compressed ``.ply`` (``*.compressed.ply``) decoded into 3DGS columns.

A PLY whose ``vertex`` element holds four ``uint`` words per Gaussian, quantised against the bounds
of its block of 256 (the ``chunk`` element, one row per block):

- ``packed_position``: x, y, z as 11, 10, 11 bits (high to low) between the block's ``min_*`` and
  ``max_*``;
- ``packed_rotation``: the quaternion (w, x, y, z) with its largest component left out: its index
  in the top 2 bits, the other three (in order) as 10 bits each over [-1/√2, 1/√2];
- ``packed_scale``: the log standard deviations as 11, 10, 11 bits between ``min_scale_*`` and
  ``max_scale_*``;
- ``packed_color``: r, g, b, a as 8 bits each, colour ``0.5 + C0 f_dc`` between the block's
  ``min_r..max_b`` (when the chunk has them; else in [0, 1]) and a = the opacity (sigmoid).

An optional ``sh`` element holds the higher SH coefficients as bytes (``(b + 0.5) / 256``, 0 and
255 exact, times 8 around 0.5). Checked against files written and decoded by PlayCanvas's
``splat-transform`` (``tests/test_splat_formats.py``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .ply import C0, PlyFormatError, element_table, opacity_logit
from .smallest_three import drop_largest, restore_largest

CHUNK = 256
_SQRT2 = math.sqrt(2.0)
CHUNK_BOUNDS = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z", "min_scale_x", "min_scale_y", "min_scale_z",
                "max_scale_x", "max_scale_y", "max_scale_z")
PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")


def _unorm(words: np.ndarray, shift: int, bits: int) -> np.ndarray:
    top = (1 << bits) - 1
    return ((words >> np.uint32(shift)) & np.uint32(top)).astype(np.float64) / top


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    return a * (1.0 - t) + b * t


def decode_compressed_ply(data: bytes, header, vertex: dict[str, np.ndarray], path: Path) -> dict[str, np.ndarray]:
    """The 3DGS columns (x.., f_dc_*, f_rest_*, opacity, scale_*, rot_*) of a compressed PLY whose
    vertex columns are ``vertex``. Raises ``PlyFormatError`` naming the file."""
    names = [e.name for e in header.elements]
    missing = [p for p in PACKED if p not in vertex]
    if missing or "chunk" not in names:
        raise PlyFormatError(f"{path}: a compressed PLY needs a 'chunk' element and vertex properties {list(PACKED)}; "
                             f"found elements {names} and vertex properties {list(vertex)}")
    chunk = element_table(data, header, "chunk", path)
    lacking = [p for p in CHUNK_BOUNDS if p not in chunk]
    if lacking:
        raise PlyFormatError(f"{path}: the compressed PLY's chunk element lacks {lacking}")
    n = len(vertex["packed_position"])
    blocks = len(chunk["min_x"])
    if blocks * CHUNK < n:
        raise PlyFormatError(f"{path}: {n} Gaussians need {math.ceil(n / CHUNK)} chunk rows of {CHUNK}, the file "
                             f"holds {blocks}")
    bad = [p for p in chunk if not np.all(np.isfinite(chunk[p]))]
    if bad:
        raise PlyFormatError(f"{path}: non-finite chunk bounds in {bad}")
    words = {p: vertex[p].astype(np.uint32) for p in PACKED}
    ci = np.arange(n) // CHUNK
    c = {k: v[ci] for k, v in chunk.items()}
    out = {}
    pp = words["packed_position"]
    for axis, shift, bits in (("x", 21, 11), ("y", 11, 10), ("z", 0, 11)):
        out[axis] = _lerp(c[f"min_{axis}"], c[f"max_{axis}"], _unorm(pp, shift, bits))
    ps = words["packed_scale"]
    for k, (axis, shift, bits) in enumerate((("x", 21, 11), ("y", 11, 10), ("z", 0, 11))):
        out[f"scale_{k}"] = _lerp(c[f"min_scale_{axis}"], c[f"max_scale_{axis}"], _unorm(ps, shift, bits))
    pr = words["packed_rotation"]
    three = np.stack([(_unorm(pr, shift, 10) - 0.5) * _SQRT2 for shift in (20, 10, 0)], 1)
    q = restore_largest((pr >> np.uint32(30)).astype(np.int64), three)
    for k in range(4):
        out[f"rot_{k}"] = q[:, k]
    pc = words["packed_color"]
    rgb = [_unorm(pc, shift, 8) for shift in (24, 16, 8)]
    has_colour_bounds = all(f"{m}_{ch}" in chunk for m in ("min", "max") for ch in "rgb")
    for k, ch in enumerate("rgb"):
        value = _lerp(c[f"min_{ch}"], c[f"max_{ch}"], rgb[k]) if has_colour_bounds else rgb[k]
        out[f"f_dc_{k}"] = (value - 0.5) / C0
    out["opacity"] = opacity_logit(_unorm(pc, 0, 8))
    if "sh" in names:
        sh = element_table(data, header, "sh", path)
        for key, b in sh.items():
            if key.startswith("f_rest_"):
                nrm = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256.0))
                out[key] = (nrm - 0.5) * 8.0
    return out


def morton_order(means: np.ndarray, bits: int = 10) -> np.ndarray:
    """Indices that put ``means`` (N,3) in Morton (Z-curve) order on a 2^bits grid over their box, so
    that each block of 256 is compact and quantised finely."""
    lo, hi = means.min(0), means.max(0)
    cells = np.clip(((means - lo) / np.maximum(hi - lo, 1e-12) * ((1 << bits) - 1)).round(), 0, (1 << bits) - 1)
    cells = cells.astype(np.uint64)
    code = np.zeros(len(means), np.uint64)
    for b in range(bits):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + axis)
    return np.argsort(code, kind="stable")


def _pack(t: np.ndarray, bits: int) -> np.ndarray:
    return np.clip(np.round(t * ((1 << bits) - 1)), 0, (1 << bits) - 1).astype(np.uint32)


def _span(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    width = hi - lo
    return np.where(width > 0, (v - lo) / np.where(width > 0, width, 1.0), 0.0)


def encode_compressed_ply(means, scales, rotations, opacities, colors, comments=()) -> bytes:
    """SuperSplat's compressed PLY (no higher SH) of Gaussians (N,3 means, N,3 standard deviations,
    N,4 wxyz rotations, N opacities, N,3 colours in [0, 1]), put in Morton order first."""
    means = np.asarray(means, np.float64)
    order = morton_order(means) if len(means) else np.zeros(0, np.int64)
    means = means[order]
    logs = np.clip(np.log(np.maximum(np.asarray(scales, np.float64)[order], 1e-30)), -20.0, 20.0)
    largest, three = drop_largest(np.asarray(rotations, np.float64)[order])
    colours = np.clip(np.asarray(colors, np.float64)[order], 0.0, 1.0)
    alpha = np.clip(np.asarray(opacities, np.float64)[order], 0.0, 1.0)
    n = len(means)
    blocks = max(1, math.ceil(n / CHUNK))
    ci = np.arange(n) // CHUNK
    chunk = np.zeros((blocks, 18), np.float32)
    for b in range(blocks):
        sl = slice(b * CHUNK, min(n, (b + 1) * CHUNK))
        if sl.start >= n:
            continue
        for k, v in enumerate((means[sl], logs[sl], colours[sl])):
            chunk[b, 6 * k:6 * k + 3] = v.min(0)
            chunk[b, 6 * k + 3:6 * k + 6] = v.max(0)
    c = chunk.astype(np.float64)[ci]
    t = _span(means, c[:, 0:3], c[:, 3:6])
    position = (_pack(t[:, 0], 11) << 21) | (_pack(t[:, 1], 10) << 11) | _pack(t[:, 2], 11)
    t = _span(logs, c[:, 6:9], c[:, 9:12])
    scale = (_pack(t[:, 0], 11) << 21) | (_pack(t[:, 1], 10) << 11) | _pack(t[:, 2], 11)
    words = _pack(three / _SQRT2 + 0.5, 10)  # the other three in order, from the high bits down
    rotation = (largest.astype(np.uint32) << 30) | (words[:, 0] << 20) | (words[:, 1] << 10) | words[:, 2]
    t = _span(colours, c[:, 12:15], c[:, 15:18])
    colour = (_pack(t[:, 0], 8) << 24) | (_pack(t[:, 1], 8) << 16) | (_pack(t[:, 2], 8) << 8) | _pack(alpha, 8)
    names = [f"{m}_{a}" for m in ("min", "max") for a in "xyz"] + [f"{m}_scale_{a}" for m in ("min", "max")
                                                                     for a in "xyz"] + \
        [f"{m}_{a}" for m in ("min", "max") for a in "rgb"]
    lines = ["ply", "format binary_little_endian 1.0"] + [f"comment {x}" for x in comments] + \
        [f"element chunk {blocks}"] + [f"property float {x}" for x in names] + \
        [f"element vertex {n}"] + [f"property uint {x}" for x in PACKED] + ["end_header"]
    vertex = np.stack([position, rotation, scale, colour], 1).astype("<u4")
    return ("\n".join(lines) + "\n").encode("ascii") + chunk.astype("<f4").tobytes() + vertex.tobytes()
