"""Niantic's ``.spz``: Gaussians quantised column by column, gzip- (versions 2-3) or per-column
zstd-compressed (version 4), read as data.

Header (16 bytes; 32 from version 4): magic ``NGSP``, version, count, SH degree, fractional bits,
flags (1: trained with antialiasing), then (v4) the number of streams and the offset of their table.
Columns: positions (3 x signed 24-bit fixed point with the fractional bits), opacities (uint8,
the sigmoid), colours (uint8: ``f_dc * 0.15 + 0.5``), log standard deviations (uint8: ``(log + 10)
* 16``), rotations (v2: x, y, z as uint8 over [-1, 1] with w >= 0 derived; v3-4: "smallest three",
the largest component's index in the top 2 bits and the other three as 9-bit magnitudes over
[0, 1/√2] with a sign bit), and the higher SH (uint8 around 128, coefficient by coefficient with
the colour channels inside). Read in the frame ``splat-transform`` (PlayCanvas, using Niantic's own
library) reads it in, the 3DGS ``.ply``'s; checked against its decoding
(``tests/test_splat_formats.py``). Every size is checked before a column is read; compressed
streams must unpack to exactly the size the header implies.
"""

from __future__ import annotations

import gzip
import io
import math
import struct
from pathlib import Path

import numpy as np

from .ply import C0, PlyFormatError, num_rest_coefficients, opacity_logit
from .smallest_three import drop_largest, restore_largest

MAGIC = 0x5053474E  # "NGSP"
COLOR_SCALE = 0.15
MAX_GAUSSIANS = 1 << 28


def is_spz(data: bytes) -> bool:
    return data[:2] == b"\x1f\x8b" or (len(data) >= 4 and struct.unpack_from("<I", data)[0] == MAGIC)


def _gunzip(data: bytes, path: Path, limit: int) -> bytes:
    try:
        with gzip.GzipFile(fileobj=io.BytesIO(data)) as f:
            out = f.read(limit + 1)
    except (OSError, EOFError, ValueError) as exc:
        raise PlyFormatError(f"{path}: a .spz file whose gzip stream cannot be unpacked ({exc})") from None
    if len(out) > limit:
        raise PlyFormatError(f"{path}: a .spz file unpacking to more than {limit} bytes")
    return out


def decode_spz(data: bytes, path: Path) -> tuple[dict[str, np.ndarray], tuple[str, ...]]:
    """(the 3DGS columns, comments such as 'spz version 4, antialiased') of a ``.spz`` file's bytes.
    Raises ``PlyFormatError`` naming the file."""
    def fail(msg):
        return PlyFormatError(f"{path}: {msg}")

    if data[:2] == b"\x1f\x8b":
        data = _gunzip(data, path, 16 + MAX_GAUSSIANS * 64)
    if len(data) < 16 or struct.unpack_from("<I", data)[0] != MAGIC:
        raise fail("not a .spz file (no 'NGSP' header)")
    version, n = struct.unpack_from("<II", data, 4)
    degree, frac, flags = data[12], data[13], data[14]
    if version not in (2, 3, 4):
        raise fail(f".spz version {version}; versions 2, 3 and 4 are read")
    if degree not in (0, 1, 2, 3):
        raise fail(f"SH degree {degree}; 0-3 are read")
    if n > MAX_GAUSSIANS:
        raise fail(f"{n} Gaussians declared, more than this reader takes ({MAX_GAUSSIANS})")
    rot_width = 3 if version == 2 else 4
    sizes = [n * 9, n, n * 3, n * 3, n * rot_width] + ([n * num_rest_coefficients(degree)] if degree else [])
    if version >= 4:
        if len(data) < 32:
            raise fail("truncated .spz header (version 4 has 32 bytes)")
        count, toc = data[15], struct.unpack_from("<I", data, 16)[0]
        if count != len(sizes) or toc < 32 or toc + 16 * count > len(data):
            raise fail(f"a .spz stream table that does not fit: {count} streams at byte {toc} (expected {len(sizes)})")
        try:
            import zstandard
        except ImportError:
            raise fail("a version 4 .spz file needs the 'zstandard' package (pip install zstandard)") from None
        pos = toc + 16 * count
        streams = []
        for i in range(count):
            packed, unpacked = struct.unpack_from("<QQ", data, toc + 16 * i)
            if unpacked != sizes[i] or pos + packed > len(data):
                raise fail(f".spz stream {i}: {unpacked} bytes unpacked from {packed} at byte {pos}; expected "
                           f"{sizes[i]} within the file's {len(data)} bytes")
            try:
                raw = zstandard.ZstdDecompressor().decompress(data[pos:pos + packed], max_output_size=sizes[i])
            except zstandard.ZstdError as exc:
                raise fail(f".spz stream {i} cannot be unpacked ({exc})") from None
            if len(raw) != sizes[i]:
                raise fail(f".spz stream {i} unpacks to {len(raw)} bytes, not {sizes[i]}")
            streams.append(raw)
            pos += packed
    else:
        need = 16 + sum(sizes)
        if len(data) < need:
            raise fail(f"truncated .spz data: {n} Gaussians need {need} bytes, the file unpacks to {len(data)}")
        streams, pos = [], 16
        for s in sizes:
            streams.append(data[pos:pos + s])
            pos += s
    b = [np.frombuffer(s, np.uint8) for s in streams]
    p = b[0].reshape(n, 3, 3).astype(np.int32)
    fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
    fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
    means = fixed.astype(np.float64) / (1 << frac)
    out = {axis: means[:, k] for k, axis in enumerate("xyz")}
    out["opacity"] = opacity_logit(b[1].astype(np.float64) / 255.0)
    colours = b[2].reshape(n, 3).astype(np.float64)
    logs = b[3].reshape(n, 3).astype(np.float64) / 16.0 - 10.0
    for k in range(3):
        out[f"f_dc_{k}"] = (colours[:, k] / 255.0 - 0.5) / COLOR_SCALE
        out[f"scale_{k}"] = logs[:, k]
    if version == 2:
        xyz = b[4].reshape(n, 3).astype(np.float64) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - (xyz ** 2).sum(1)))
        q = np.concatenate([w[:, None], xyz], 1)
    else:
        packed = np.frombuffer(streams[4], "<u4").astype(np.int64)
        words = np.stack([(packed >> shift) & 1023 for shift in (20, 10, 0)], 1)  # the other three, in order
        three = math.sqrt(0.5) * (words & 511) / 511.0 * np.where((words >> 9) & 1, -1.0, 1.0)
        q = restore_largest(packed >> 30, three)[:, [3, 0, 1, 2]]  # stored x, y, z, w
    for k in range(4):
        out[f"rot_{k}"] = q[:, k]
    if degree:
        m = num_rest_coefficients(degree)
        sh = (b[5].reshape(n, m).astype(np.float64) - 128.0) / 128.0
        per = m // 3
        for c in range(m):  # stored coefficient by coefficient, channels inside; 3DGS keeps channels outside
            out[f"f_rest_{(c % 3) * per + c // 3}"] = sh[:, c]
    comments = (f"spz version {version}" + (", antialiased" if flags & 1 else ""),)
    return out, comments


def encode_spz(means, scales, rotations, opacities, colors, *, version: int = 3, fractional_bits: int = 12) -> bytes:
    """The ``.spz`` bytes (SH degree 0) of Gaussians (N,3 means, N,3 standard deviations, N,4 wxyz
    rotations, N opacities, N,3 colours in [0, 1]) in the order given: version 3 (one gzip
    stream, what every reader takes) or 4 (a zstd stream per column). ``fractional_bits`` (12:
    0.24 mm steps, +-2 km) sets the positions' fixed point."""
    if version not in (3, 4):
        raise ValueError(f".spz version {version}: 3 or 4 are written")
    means = np.asarray(means, np.float64)
    n = len(means)
    fixed = np.round(means * (1 << fractional_bits)).astype(np.int64)
    if np.any(np.abs(fixed) >= 1 << 23):
        raise ValueError(f"positions beyond +-{(1 << 23) / (1 << fractional_bits):g} m do not fit .spz's 24-bit "
                         f"fixed point with {fractional_bits} fractional bits")
    fixed &= 0xFFFFFF
    positions = np.stack([(fixed >> s) & 0xFF for s in (0, 8, 16)], -1).astype(np.uint8).reshape(n, 9)

    def u8(v):
        return np.clip(np.round(v), 0, 255).astype(np.uint8)

    alphas = u8(np.asarray(opacities, np.float64) * 255.0)
    f_dc = (np.asarray(colors, np.float64) - 0.5) / C0
    colours = u8((f_dc * COLOR_SCALE + 0.5) * 255.0)
    logs = np.log(np.maximum(np.asarray(scales, np.float64), 1e-30))
    scale_bytes = u8((logs + 10.0) * 16.0)
    largest, three = drop_largest(np.asarray(rotations, np.float64)[:, [1, 2, 3, 0]])  # stored x, y, z, w
    magnitude = np.clip(np.round(np.abs(three) / math.sqrt(0.5) * 511), 0, 511).astype(np.int64)
    words = (np.where(three < 0, 1, 0) << 9) | magnitude  # the other three in order, from the high bits down
    packed = (largest.astype(np.int64) << 30) | (words[:, 0] << 20) | (words[:, 1] << 10) | words[:, 2]
    rotation_bytes = packed.astype("<u4").tobytes()
    columns = [positions.tobytes(), alphas.tobytes(), colours.tobytes(), scale_bytes.tobytes(), rotation_bytes]
    if version == 3:
        header = struct.pack("<IIIBBBB", MAGIC, 3, n, 0, fractional_bits, 0, 0)
        return gzip.compress(header + b"".join(columns), mtime=0)
    import zstandard

    packed_columns = [zstandard.ZstdCompressor(level=12).compress(c) for c in columns]
    toc_offset = 32
    header = struct.pack("<IIIBBBBI", MAGIC, 4, n, 0, fractional_bits, 0, len(columns), toc_offset) + bytes(12)
    toc = b"".join(struct.pack("<QQ", len(p), len(c)) for p, c in zip(packed_columns, columns))
    return header + toc + b"".join(packed_columns)
