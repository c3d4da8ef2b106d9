"""PlayCanvas's SOG (``.sog``, SuperSplat's web export): Gaussians as lossless WebP images plus a
``meta.json``, in a zip archive (``.sog``) or a folder (``meta.json`` beside its images). Read as
data: version 2, the layout SuperSplat and splat-transform write; ``encode_sog`` writes it (without
higher SH).

Texel i of every image holds Gaussian i (row by row). ``meta.json`` gives the count and, per
attribute, its images and how to decode them:

- ``means``: two images, the low and high bytes of 16-bit values per axis between ``mins`` and
  ``maxs`` of ``sign(x) log(1 + |x|)``, undone by ``sign(v) (exp(|v|) - 1)``;
- ``quats``: the quaternion (w, x, y, z) without its largest component, whose index is the alpha
  byte minus 252; the other three in order as bytes over [-1/√2, 1/√2];
- ``scales``: three bytes indexing a 256-entry ``codebook`` of log standard deviations;
- ``sh0``: three bytes indexing a ``codebook`` of degree-0 SH coefficients, alpha = the opacity;
- ``shN`` (optional): a palette of higher-SH centroids and a 16-bit label per Gaussian (read for
  the SH degree only: ours are view-independent).

Archive members are read only by the names ``meta.json`` gives, each checked for size before it is
unpacked; a folder's names may not leave it. Checked against splat-transform's own decoding
(``tests/test_splat_formats.py``).
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np

from .ply import C0, PlyFormatError, num_rest_coefficients, opacity_logit
from .smallest_three import drop_largest, restore_largest

MAX_MEMBER = 1 << 30  # bytes unpacked from one archive member
MAX_GAUSSIANS = 1 << 28


def is_sog(path: Path, head: bytes) -> bool:
    return path.name.lower() == "meta.json" or (path.suffix.lower() == ".sog" and head[:2] == b"PK")


class _Files:
    """The images and meta.json of a .sog archive or a meta.json folder."""

    def __init__(self, path: Path) -> None:
        self.path, self.zip = path, None
        if path.name.lower() != "meta.json":
            try:
                self.zip = zipfile.ZipFile(path)
            except (zipfile.BadZipFile, OSError) as exc:
                raise PlyFormatError(f"{path}: not a .sog archive ({exc})") from None

    def read(self, name: str) -> bytes:
        if not isinstance(name, str) or not name:
            raise PlyFormatError(f"{self.path}: meta.json names a file {name!r}")
        if self.zip is not None:
            try:
                info = self.zip.getinfo(name)
            except KeyError:
                raise PlyFormatError(f"{self.path}: the archive has no {name!r}, which meta.json names") from None
            if info.file_size > MAX_MEMBER:
                raise PlyFormatError(f"{self.path}: {name!r} unpacks to {info.file_size} bytes, more than {MAX_MEMBER}")
            with self.zip.open(info) as f:
                data = f.read(MAX_MEMBER + 1)
            if len(data) > MAX_MEMBER:
                raise PlyFormatError(f"{self.path}: {name!r} unpacks to more than {MAX_MEMBER} bytes")
            return data
        folder = self.path.parent.resolve()
        target = (folder / name).resolve()
        if folder not in target.parents:
            raise PlyFormatError(f"{self.path}: meta.json names {name!r}, outside its folder")
        try:
            return target.read_bytes()
        except OSError as exc:
            raise PlyFormatError(f"{self.path}: {name!r}, which meta.json names, cannot be read: {exc}") from None


def _image(files: _Files, name: str, count: int) -> np.ndarray:
    """(count, 4) uint8 RGBA texels of a lossless WebP, row by row."""
    from PIL import Image, UnidentifiedImageError

    data = files.read(name)
    try:
        with Image.open(io.BytesIO(data)) as im:
            if im.width * im.height > 4 * MAX_GAUSSIANS:
                raise PlyFormatError(f"{files.path}: {name!r} is {im.width} x {im.height} pixels, too large")
            rgba = np.asarray(im.convert("RGBA"), np.uint8).reshape(-1, 4)
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise PlyFormatError(f"{files.path}: {name!r} is not an image that can be read ({exc})") from None
    if len(rgba) < count:
        raise PlyFormatError(f"{files.path}: {name!r} holds {len(rgba)} texels, fewer than the {count} Gaussians")
    return rgba[:count]


def _codebook(meta: dict, key: str, path: Path) -> np.ndarray:
    book = np.asarray(meta[key].get("codebook", []), np.float64)
    if book.shape != (256,) or not np.all(np.isfinite(book)):
        raise PlyFormatError(f"{path}: meta.json {key}.codebook must hold 256 finite numbers, found {book.shape}")
    return book


def decode_sog(path: Path) -> tuple[dict[str, np.ndarray], tuple[str, ...]]:
    """(the 3DGS columns, comments) of a ``.sog`` archive or a SOG ``meta.json``. Raises
    ``PlyFormatError`` naming the file."""
    files = _Files(path)
    try:
        meta = json.loads(files.read("meta.json").decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PlyFormatError(f"{path}: its meta.json is not JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise PlyFormatError(f"{path}: its meta.json is not an object")
    version = meta.get("version")
    if version != 2:
        raise PlyFormatError(f"{path}: SOG version {version!r}; version 2 (SuperSplat, splat-transform 1.x and "
                             f"later) is read; re-export the file")
    try:
        count = int(meta["count"])
        files_of = {k: list(meta[k]["files"]) for k in ("means", "quats", "scales", "sh0")}
        mins = np.asarray(meta["means"]["mins"], np.float64)
        maxs = np.asarray(meta["means"]["maxs"], np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise PlyFormatError(f"{path}: meta.json lacks {exc} (count, means, quats, scales, sh0)") from None
    if not 0 < count <= MAX_GAUSSIANS:
        raise PlyFormatError(f"{path}: meta.json count {count}: expected 1 to {MAX_GAUSSIANS} Gaussians")
    if mins.shape != (3,) or maxs.shape != (3,) or len(files_of["means"]) != 2:
        raise PlyFormatError(f"{path}: meta.json means needs 3 mins, 3 maxs and 2 files")
    lo, hi = (_image(files, n, count) for n in files_of["means"])
    out = {}
    for k, axis in enumerate("xyz"):
        v = (lo[:, k].astype(np.float64) + 256.0 * hi[:, k]) / 65535.0
        v = mins[k] + (maxs[k] - mins[k]) * v
        out[axis] = np.sign(v) * np.expm1(np.abs(v))
    quats = _image(files, files_of["quats"][0], count)
    tag = quats[:, 3].astype(np.int64) - 252
    abc = (quats[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / math.sqrt(2.0)
    valid = (tag >= 0) & (tag <= 3)
    q = restore_largest(np.where(valid, tag, 0), abc)
    q[~valid] = (1.0, 0.0, 0.0, 0.0)
    for k in range(4):
        out[f"rot_{k}"] = q[:, k]
    scales = _image(files, files_of["scales"][0], count)
    book = _codebook(meta, "scales", path)
    sh0 = _image(files, files_of["sh0"][0], count)
    colours = _codebook(meta, "sh0", path)
    for k in range(3):
        out[f"scale_{k}"] = book[scales[:, k]]
        out[f"f_dc_{k}"] = colours[sh0[:, k]]
    out["opacity"] = opacity_logit(sh0[:, 3].astype(np.float64) / 255.0)
    bands = int((meta.get("shN") or {}).get("bands", 0) or 0)
    if bands not in (0, 1, 2, 3):
        raise PlyFormatError(f"{path}: meta.json shN.bands {bands}: 0-3 are read")
    for k in range(num_rest_coefficients(bands)):  # the degree only: higher SH are not drawn here
        out[f"f_rest_{k}"] = np.zeros(count)
    return out, (f"sog version {version}",)


def _codebook_of(values: np.ndarray, k: int = 256, iterations: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """(a sorted 1-D codebook of ``k`` entries, each value's nearest entry as uint8): quantiles,
    refined by a few Lloyd steps."""
    v = np.asarray(values, np.float64).ravel()
    book = np.quantile(v, (np.arange(k) + 0.5) / k)
    for _ in range(iterations):
        cuts = (book[1:] + book[:-1]) / 2
        label = np.searchsorted(cuts, v)
        sums = np.bincount(label, v, minlength=k)
        counts = np.bincount(label, minlength=k)
        book = np.where(counts > 0, sums / np.maximum(counts, 1), book)
        book = np.sort(book)
    label = np.searchsorted((book[1:] + book[:-1]) / 2, v)
    return book, label.astype(np.uint8).reshape(np.shape(values))


def _webp(rgba: np.ndarray, width: int, height: int) -> bytes:
    from PIL import Image

    texels = np.zeros((width * height, 4), np.uint8)
    texels[: len(rgba)] = rgba
    buf = io.BytesIO()
    # lossless, and exact: the colour under an alpha of 0 (a transparent Gaussian) is data too
    Image.fromarray(texels.reshape(height, width, 4), "RGBA").save(buf, "WEBP", lossless=True, quality=100,
                                                                   method=4, exact=True)
    return buf.getvalue()


def encode_sog(means, scales, rotations, opacities, colors) -> bytes:
    """A ``.sog`` archive (version 2, no higher SH) of Gaussians (N,3 means, N,3 standard
    deviations, N,4 wxyz rotations, N opacities, N,3 colours in [0, 1]), put in Morton order."""
    from .compressed_ply import morton_order

    means = np.asarray(means, np.float64)
    n = len(means)
    if n == 0:
        raise ValueError("a .sog file needs at least one Gaussian")
    order = morton_order(means)
    means = means[order]
    width = int(math.ceil(math.sqrt(n)))
    height = int(math.ceil(n / width))
    logged = np.sign(means) * np.log1p(np.abs(means))
    lo_, hi_ = logged.min(0), logged.max(0)
    q16 = np.round((logged - lo_) / np.where(hi_ > lo_, hi_ - lo_, 1.0) * 65535.0).astype(np.int64)
    opaque = np.full((n, 1), 255, np.uint8)
    means_l = np.concatenate([(q16 & 255).astype(np.uint8), opaque], 1)
    means_u = np.concatenate([(q16 >> 8).astype(np.uint8), opaque], 1)
    largest, three = drop_largest(np.asarray(rotations, np.float64)[order])
    quats = np.zeros((n, 4), np.uint8)
    quats[:, :3] = np.clip(np.round((three * math.sqrt(2.0) + 1.0) / 2.0 * 255.0), 0, 255)
    quats[:, 3] = 252 + largest
    scale_book, scale_label = _codebook_of(np.log(np.maximum(np.asarray(scales, np.float64)[order], 1e-30)))
    f_dc = (np.clip(np.asarray(colors, np.float64)[order], 0.0, 1.0) - 0.5) / C0
    colour_book, colour_label = _codebook_of(f_dc)
    alpha = np.clip(np.round(np.asarray(opacities, np.float64)[order] * 255.0), 0, 255).astype(np.uint8)
    images = {"means_l.webp": means_l, "means_u.webp": means_u, "quats.webp": quats,
              "scales.webp": np.concatenate([scale_label, opaque], 1),
              "sh0.webp": np.concatenate([colour_label, alpha[:, None]], 1)}
    meta = {"version": 2, "asset": {"generator": "WonderHuman Studio"}, "count": n,
            "means": {"mins": lo_.tolist(), "maxs": hi_.tolist(), "files": ["means_l.webp", "means_u.webp"]},
            "scales": {"codebook": scale_book.tolist(), "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]},
            "sh0": {"codebook": colour_book.tolist(), "files": ["sh0.webp"]}}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:  # the images are compressed already
        for name, rgba in images.items():
            z.writestr(zipfile.ZipInfo(name, (1980, 1, 1, 0, 0, 0)), _webp(rgba, width, height))
        z.writestr(zipfile.ZipInfo("meta.json", (1980, 1, 1, 0, 0, 0)), json.dumps(meta))
    return buf.getvalue()
