"""Gaussians as ``.ply`` files in the 3D Gaussian Splatting layout, readable by splat viewers
(SuperSplat, antimatter15/splat, gsplat's viewer, nerfstudio ...) and by this program.

Layout written (``docs/ply.md``): one ``vertex`` element, binary little endian, every property
``float`` (float32), in the order of the reference 3DGS code's ``save_ply``::

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{K-1}  opacity  scale_0..2  rot_0..3

- ``f_dc`` = (rgb - 0.5) / C0, C0 = 0.28209479177387814 (the degree-0 SH basis): a viewer's
  ``0.5 + C0 f_dc`` gives the colour back. ``f_rest``: K = 3((d+1)² - 1) zeros for SH degree d
  (45 for d = 3, what most viewers expect; none for d = 0). Our Gaussians have view-independent
  colour, so the higher coefficients are zero.
- ``opacity``: the logit of the opacity (clamped to [1e-6, 1 - 1e-6] first: the avatar's opacities
  are exactly 1, whose logit is infinite).
- ``scale_i``: natural log of the standard deviation (clamped to >= 1e-8).
- ``rot_0..3``: the normalised rotation quaternion, w first.

Frames: our world is Z up with the avatar facing -Y; viewers tuned for 3DGS captures expect the
OpenCV/COLMAP convention (y down). ``up="y_down"`` (default) writes the avatar rotated by
``UP_ROTATION`` (x' = x, y' = -z, z' = y: upright with -Y up, facing -Z); means, normals and
rotations are transformed together. ``up="z_up"`` writes our frame as it is. The choice is recorded
in a header line ``comment wonderhuman up=<up>``, which ``read_gaussians_ply`` undoes (files
without it are returned as they are).

Reading needs numpy only: any 3DGS file, binary (either endian) or ascii, SH degree 0-3, properties
in any order, extra properties ignored, normals optional. Errors (``PlyFormatError``) name the file
and what was expected and found.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from .atomic import _UMASK, atomic_output
from .snapshot import Snapshot

C0 = 0.28209479177387814  # the degree-0 real spherical harmonic, 1 / (2 sqrt(pi))
OPACITY_EPS = 1e-6
MIN_SCALE = 1e-8
UP_CHOICES = ("y_down", "z_up")
# ours (Z up, facing -Y) -> y_down (Y down, facing -Z): x' = x, y' = -z, z' = y
UP_ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
UP_QUATERNION = np.array([math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0])  # the same rotation, wxyz
MARKER = "wonderhuman"
HEADER_LIMIT = 1 << 20  # a header longer than this is not a 3DGS file

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
    "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}
FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": None}
REQUIRED = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
            "rot_0", "rot_1", "rot_2", "rot_3")


class PlyFormatError(ValueError):
    """A file that is not a readable 3DGS ``.ply``: the message names the file, what was expected
    and what was found."""


def num_rest_coefficients(sh_degree: int) -> int:
    """f_rest properties for SH degree ``sh_degree``: 3 ((d+1)² - 1) (45 for degree 3)."""
    return 3 * ((sh_degree + 1) ** 2 - 1)


def property_names(sh_degree: int = 3, normals: bool = True) -> list[str]:
    """The vertex properties written, in order."""
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals else [])
    names += [f"f_dc_{i}" for i in range(3)] + [f"f_rest_{i}" for i in range(num_rest_coefficients(sh_degree))]
    return names + ["opacity"] + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]


# ----- quaternions (w, x, y, z) ----------------------------------------------------------------
def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b (rotation b, then a), broadcasting over leading axes."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, np.float64), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def _to_frame(up: str, means, normals, rotations, inverse: bool = False):
    """Means, normals, rotations (float64) moved from our frame to ``up``'s (or back)."""
    if up == "z_up":
        return means, normals, rotations
    R = UP_ROTATION.T if inverse else UP_ROTATION
    q = UP_QUATERNION * (np.array([1.0, -1.0, -1.0, -1.0]) if inverse else 1.0)
    return means @ R.T, (None if normals is None else normals @ R.T), quat_multiply(q, rotations)


# ----- writing ----------------------------------------------------------------------------------
def _as_rows(name: str, value, n: int | None, width: int | None) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != (1 if width is None else 2) or (width is not None and a.shape[1] != width) \
            or (n is not None and a.shape[0] != n):
        expect = f"({n if n is not None else 'N'},{'' if width is None else f' {width}'})"
        raise ValueError(f"{name}: expected shape {expect}, found {a.shape}")
    bad = ~np.isfinite(a).reshape(a.shape[0], -1).all(axis=1)
    if bad.any():
        raise ValueError(f"{name}: {int(bad.sum())} rows hold NaN or inf (first: row {int(np.argmax(bad))})")
    return a


def opacity_logit(opacities, eps: float = OPACITY_EPS) -> np.ndarray:
    """The logit of opacities, clamped to [eps, 1 - eps] first (an opacity of exactly 1 or 0 has an
    infinite logit)."""
    p = np.clip(np.asarray(opacities, np.float64), eps, 1.0 - eps)
    return np.log(p / (1.0 - p))


def checked_gaussians(means, scales, rotations, opacities, colors, normals=None, *, up: str = "y_down"):
    """(means, scales, rotations, opacities, colors, normals) as float64 arrays, checked and moved
    into ``up``'s frame with unit rotations (normals zero when None). Raises ValueError for an
    unknown ``up``, wrong shapes, NaN/inf or zero quaternions."""
    if up not in UP_CHOICES:
        raise ValueError(f"up must be one of {UP_CHOICES}, found {up!r}")
    means = _as_rows("means", means, None, 3)
    n = means.shape[0]
    scales = _as_rows("scales", scales, n, 3)
    rotations = _as_rows("rotations", rotations, n, 4)
    opacities = _as_rows("opacities", opacities, n, None)
    colors = _as_rows("colors", colors, n, 3)
    normals = np.zeros((n, 3)) if normals is None else _as_rows("normals", normals, n, 3)
    norm = np.linalg.norm(rotations, axis=1, keepdims=True)
    if np.any(norm == 0):
        raise ValueError(f"rotations: {int((norm == 0).sum())} quaternions are zero (first: row "
                         f"{int(np.argmax(norm[:, 0] == 0))})")
    means, normals, rotations = _to_frame(up, means, normals, rotations / norm)
    rotations /= np.linalg.norm(rotations, axis=1, keepdims=True)
    return means, scales, rotations, opacities, colors, normals


def gaussian_rows(means, scales, rotations, opacities, colors, normals=None, *, up: str = "y_down",
                  sh_degree: int = 3) -> np.ndarray:
    """The (N, P) float32 table of vertex properties, in ``property_names`` order (see the module
    docstring for the encodings). Raises ValueError for wrong shapes, NaN/inf or zero quaternions."""
    if sh_degree not in (0, 1, 2, 3):
        raise ValueError(f"sh_degree must be 0, 1, 2 or 3, found {sh_degree!r}")
    means, scales, rotations, opacities, colors, normals = checked_gaussians(
        means, scales, rotations, opacities, colors, normals, up=up)
    n = means.shape[0]
    k = num_rest_coefficients(sh_degree)
    table = np.empty((n, 3 + 3 + 3 + k + 1 + 3 + 4), np.float32)
    table[:, 0:3] = means
    table[:, 3:6] = normals
    table[:, 6:9] = (colors - 0.5) / C0
    table[:, 9:9 + k] = 0.0
    table[:, 9 + k] = opacity_logit(opacities)
    table[:, 10 + k:13 + k] = np.log(np.maximum(scales, MIN_SCALE))
    table[:, 13 + k:17 + k] = rotations
    return table


def ply_header(n: int, names: Sequence[str], comments: Iterable[str] = ()) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0"]
    for c in comments:
        c = str(c)
        if "\n" in c or "\r" in c:
            raise ValueError(f"a PLY comment must be one line, found {c!r}")
        lines.append(f"comment {c}".rstrip())
    lines.append(f"element vertex {n}")
    lines += [f"property float {name}" for name in names]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii", errors="strict")


def write_gaussians_ply(path, means, scales, rotations, opacities, colors, normals=None, *, up: str = "y_down",
                        sh_degree: int = 3, comments: Iterable[str] = ()) -> Path:
    """Write Gaussians (numpy arrays as in ``Snapshot``: means (N,3), scales (N,3) standard
    deviations, rotations (N,4) wxyz, opacities (N,) in [0,1], colors (N,3) RGB in [0,1], normals
    (N,3) or None for zeros) to ``path`` in the 3DGS layout, atomically (a failure leaves the
    previous file or none). ``up``: "y_down" (viewers' convention, default) or "z_up" (ours).
    ``comments``: extra header comment lines (ASCII, one line each). Returns the path."""
    table = gaussian_rows(means, scales, rotations, opacities, colors, normals, up=up, sh_degree=sh_degree)
    comments = [f"{MARKER} up={up}", f"{MARKER} sh_degree={sh_degree}"] + list(comments)
    header = ply_header(table.shape[0], property_names(sh_degree), comments)
    path = Path(path)
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        f.write(header)
        f.write(np.ascontiguousarray(table, dtype="<f4").tobytes())
    return path


def snapshot_comments(snapshot: Snapshot) -> list[str]:
    """Header comments describing where a snapshot came from (informational)."""
    return [f"{MARKER} space={snapshot.space} frame={snapshot.frame_index} stage={snapshot.stage} step={snapshot.step}"]


def write_snapshot_ply(path, snapshot: Snapshot, **kw) -> Path:
    """A ``Snapshot``'s Gaussians in the layout ``path`` names (``gaussian_files.write_gaussians``:
    3DGS ``.ply``, ``.compressed.ply``, ``.splat``, ``.spz``); its space, frame, stage and step go
    into the comments of the PLY layouts."""
    from .gaussian_files import write_gaussians

    comments = snapshot_comments(snapshot) + list(kw.pop("comments", ()))
    return write_gaussians(path, snapshot.means, snapshot.scales, snapshot.rotations, snapshot.opacities,
                           snapshot.colors, snapshot.normals, comments=comments, **kw)


def write_ply_sequence(folder, snapshots: Iterable[Snapshot], *, progress: Callable[[int, int | None], None] | None = None,
                       overwrite: bool = False, suffix: str = ".ply", **kw) -> list[Path]:
    """One file per snapshot, ``frame_0000.ply``, ``frame_0001.ply`` ..., in ``folder`` (``suffix``:
    ``.compressed.ply``, ``.splat`` or ``.spz`` for those layouts).

    The files are written into a hidden temporary folder beside ``folder`` that is renamed into
    place only when every frame is written: a failed or interrupted export leaves no half-written
    sequence (and, with ``overwrite``, the previous one intact). An existing ``folder`` is an
    error unless ``overwrite``. ``progress(done, total)`` is called after each frame (total None
    when ``snapshots`` has no length). Other keywords go to ``write_snapshot_ply``. Returns the
    final paths."""
    folder = Path(folder)
    if folder.exists() and not overwrite:
        raise FileExistsError(f"{folder}: exists; pass overwrite=True to replace the sequence in it")
    folder.parent.mkdir(parents=True, exist_ok=True)
    total = len(snapshots) if hasattr(snapshots, "__len__") else None
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".partial", dir=folder.parent))
    try:
        names = []
        for i, snap in enumerate(snapshots):
            names.append(f"frame_{i:04d}{suffix}")
            write_snapshot_ply(tmp / names[-1], snap, **kw)
            if progress is not None:
                progress(i + 1, total)
        os.chmod(tmp, 0o777 & ~_UMASK)  # mkdtemp makes it 0700; give it an ordinary folder's mode
        if folder.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".old", dir=folder.parent))
            os.replace(folder, old / folder.name)
            try:
                os.replace(tmp, folder)
            except BaseException:
                os.replace(old / folder.name, folder)  # put the previous sequence back
                shutil.rmtree(old, ignore_errors=True)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [folder / n for n in names]


# ----- reading ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlyGaussians:
    """Gaussians read from a 3DGS ``.ply``, in our frame when the file says how it was written.

    means (N,3), scales (N,3) standard deviations, rotations (N,4) unit wxyz, opacities (N,) in
    (0,1), colors (N,3) from the degree-0 coefficients (``0.5 + C0 f_dc``; may leave [0,1] in
    files from other programs), normals (N,3) or None when the file has none; all float32.
    sh_degree: from the number of f_rest properties (None when it matches no degree 0-3).
    up: the frame recorded by our writer ("y_down" / "z_up", undone), or None (file as it was).
    comments: the header's comment lines."""

    means: np.ndarray
    scales: np.ndarray
    rotations: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray
    normals: np.ndarray | None
    sh_degree: int | None
    up: str | None = None
    comments: tuple[str, ...] = field(default_factory=tuple)

    def __len__(self) -> int:
        return int(self.means.shape[0])


@dataclass
class _Element:
    name: str
    count: int
    properties: list[tuple[str, str]] = field(default_factory=list)  # (name, numpy type code)
    lists: list[str] = field(default_factory=list)  # names of list properties


@dataclass
class _Header:
    fmt: str
    elements: list[_Element]
    comments: list[str]
    data_offset: int


def _parse_header(data: bytes, path: Path) -> _Header:
    def fail(msg: str) -> PlyFormatError:
        return PlyFormatError(f"{path}: {msg}")

    first = data[:5]
    if not (first.startswith(b"ply\n") or first.startswith(b"ply\r\n")):
        raise fail(f"not a PLY file: expected it to start with 'ply', found {data[:16]!r}")
    m = re.search(rb"(?m)^end_header[ \t]*\r?\n", data[:HEADER_LIMIT])
    if m is None:
        raise fail(f"the PLY header has no 'end_header' line in the first {min(len(data), HEADER_LIMIT)} bytes "
                   f"(a truncated or malformed header)")
    try:
        text = data[: m.start()].decode("ascii")
    except UnicodeDecodeError as exc:
        raise fail(f"the PLY header holds non-ASCII bytes (at byte {exc.start})") from exc
    fmt, elements, comments = None, [], []
    for lineno, line in enumerate(text.splitlines()[1:], 2):
        words = line.split()
        if not words:
            continue
        key = words[0]
        if key == "format":
            if len(words) != 3 or words[1] not in FORMATS:
                raise fail(f"header line {lineno} {line!r}: expected 'format ascii|binary_little_endian|"
                           f"binary_big_endian 1.0'")
            fmt = words[1]
        elif key == "comment":
            comments.append(line[len("comment"):].strip())
        elif key == "obj_info":
            continue
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise fail(f"header line {lineno} {line!r}: expected 'element <name> <count>'")
            elements.append(_Element(words[1], int(words[2])))
        elif key == "property":
            if not elements:
                raise fail(f"header line {lineno} {line!r}: a property before any element")
            if len(words) >= 2 and words[1] == "list":
                if len(words) != 5:
                    raise fail(f"header line {lineno} {line!r}: expected 'property list <count type> <type> <name>'")
                elements[-1].lists.append(words[4])
                elements[-1].properties.append((words[4], "list"))
                continue
            if len(words) != 3 or words[1] not in PLY_TYPES:
                raise fail(f"header line {lineno} {line!r}: expected 'property <type> <name>' with a type among "
                           f"{sorted(set(PLY_TYPES))}")
            elements[-1].properties.append((words[2], PLY_TYPES[words[1]]))
        else:
            raise fail(f"header line {lineno} {line!r}: unknown keyword {key!r}")
    if fmt is None:
        raise fail("the PLY header has no 'format' line")
    return _Header(fmt, elements, comments, m.end())


def _vertex_table(data: bytes, header: _Header, path: Path) -> tuple[dict[str, np.ndarray], int]:
    """Every scalar vertex property (float64 columns by name) and the vertex count."""
    names = [e.name for e in header.elements]
    if "vertex" not in names:
        raise PlyFormatError(f"{path}: no 'vertex' element (found elements {names or 'none'}): a 3DGS file keeps "
                             f"one Gaussian per vertex")
    return element_table(data, header, "vertex", path), header.elements[names.index("vertex")].count


def element_table(data: bytes, header: _Header, name: str, path: Path) -> dict[str, np.ndarray]:
    """Every scalar property of element ``name`` (float64 columns by property name)."""
    names = [e.name for e in header.elements]
    vi = names.index(name)
    vertex = header.elements[vi]
    if vertex.lists:
        raise PlyFormatError(f"{path}: the {name} element has list properties {vertex.lists}: a 3DGS file has only "
                             f"scalar properties")
    n = vertex.count
    props = [p for p, _ in vertex.properties]
    dups = sorted({p for p in props if props.count(p) > 1})
    if dups:
        raise PlyFormatError(f"{path}: {name} properties {dups} are declared twice")
    before = header.elements[:vi]
    body = data[header.data_offset:]
    if header.fmt == "ascii":
        return _ascii_vertices(body, header, before, vertex, path)
    endian = FORMATS[header.fmt]
    offset = 0
    for e in before:
        if e.lists:
            raise PlyFormatError(f"{path}: element {e.name!r} before {name!r} has list properties {e.lists}; "
                                 f"binary files with those before the vertices are not read")
        offset += e.count * np.dtype([(f"p{i}", endian + t) for i, (_, t) in enumerate(e.properties)]).itemsize
    dtype = np.dtype([(p, endian + t) for p, t in vertex.properties])
    need = n * dtype.itemsize
    have = len(body) - offset
    rows = "vertices" if name == "vertex" else f"{name} rows"
    if have < need:
        raise PlyFormatError(f"{path}: truncated: the header declares {n} {rows} of {dtype.itemsize} bytes "
                             f"({need} bytes), the file holds {max(have, 0)} bytes of {name} data")
    if vi == len(header.elements) - 1 and have > need and body[offset + need:].strip(b" \t\r\n\x00"):
        raise PlyFormatError(f"{path}: count mismatch: the header declares {n} {rows} ({need} bytes) but the "
                             f"file holds {have} bytes of data after the header")
    rec = np.frombuffer(body, dtype=dtype, count=n, offset=offset)
    return {p: rec[p].astype(np.float64) for p in props}


def _ascii_vertices(body: bytes, header: _Header, before: list[_Element], vertex: _Element, path: Path):
    try:
        lines = body.decode("ascii").splitlines()
    except UnicodeDecodeError as exc:
        raise PlyFormatError(f"{path}: an ascii PLY file holds non-ASCII bytes (at byte {exc.start} after the "
                             f"header)") from exc
    lines = [ln for ln in lines if ln.strip()]
    start = sum(e.count for e in before)
    n, width = vertex.count, len(vertex.properties)
    rows = lines[start:start + n]
    if len(rows) < n:
        raise PlyFormatError(f"{path}: truncated: the header declares {n} vertices, the file holds {len(rows)} "
                             f"vertex lines")
    if len(lines) > start + n and header.elements[-1] is vertex:
        raise PlyFormatError(f"{path}: count mismatch: the header declares {n} vertices, the file holds "
                             f"{len(lines) - start} vertex lines")
    tokens = " ".join(rows).split()
    if len(tokens) != n * width:
        for i, row in enumerate(rows):
            if len(row.split()) != width:
                raise PlyFormatError(f"{path}: vertex line {i} holds {len(row.split())} values, expected {width} "
                                     f"(one per property)")
    try:
        values = np.array(tokens, dtype=np.float64).reshape(n, width)
    except ValueError as exc:
        raise PlyFormatError(f"{path}: the vertex lines hold a value that is not a number ({exc})") from exc
    return {p: values[:, i] for i, (p, _) in enumerate(vertex.properties)}


def _up_of(comments: Sequence[str], path: Path) -> str | None:
    for c in comments:
        words = c.split()
        if words and words[0] == MARKER:
            for w in words[1:]:
                if w.startswith("up="):
                    up = w[3:]
                    if up not in UP_CHOICES:
                        raise PlyFormatError(f"{path}: comment {c!r}: unknown frame {up!r}, expected one of {UP_CHOICES}")
                    return up
    return None


def read_gaussians_ply(path) -> PlyGaussians:
    """Read any 3DGS ``.ply`` (see the module docstring) into ``PlyGaussians``, undoing our writer's
    ``up`` frame when the header records it. Raises ``PlyFormatError`` naming the file for: not a
    PLY, no vertex element, missing required properties (all listed), list properties, a count
    that does not match the data, truncated data, non-finite values."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PlyFormatError(f"{path}: cannot be read: {exc.strerror or exc}") from exc
    header = _parse_header(data, path)
    cols, n = _vertex_table(data, header, path)
    if "packed_position" in cols:  # PlayCanvas / SuperSplat's compressed layout
        from .compressed_ply import decode_compressed_ply

        cols = decode_compressed_ply(data, header, cols, path)
    return gaussians_from_columns(cols, tuple(header.comments), path)


def gaussians_from_columns(cols: dict[str, np.ndarray], comments: tuple[str, ...], path: Path) -> PlyGaussians:
    """``PlyGaussians`` from columns named as in the 3DGS layout (``REQUIRED``, optional normals and
    ``f_rest_*``), whichever file they came from; the checks and the ``up`` frame of
    ``read_gaussians_ply``."""
    missing = [p for p in REQUIRED if p not in cols]
    if missing:
        raise PlyFormatError(f"{path}: missing vertex properties {missing} of the 3DGS layout (found "
                             f"{list(cols)})")
    has_normals = all(k in cols for k in ("nx", "ny", "nz"))
    used = list(REQUIRED) + (["nx", "ny", "nz"] if has_normals else [])
    # an opacity logit of +-inf is opacity 1 or 0 (splat-transform writes +inf for a compressed PLY's
    # opacity byte 255); NaN anywhere, and inf elsewhere, are refused
    bad = {p: int((np.isnan(cols[p]) if p == "opacity" else ~np.isfinite(cols[p])).sum()) for p in used}
    bad = {p: k for p, k in bad.items() if k}
    if bad:
        raise PlyFormatError(f"{path}: non-finite values (NaN or inf) in vertex properties {bad} (counts)")
    stack = lambda keys: np.stack([cols[k] for k in keys], axis=1)  # noqa: E731
    means = stack(("x", "y", "z"))
    normals = stack(("nx", "ny", "nz")) if has_normals else None
    rotations = stack(("rot_0", "rot_1", "rot_2", "rot_3"))
    norm = np.linalg.norm(rotations, axis=1, keepdims=True)
    if np.any(norm == 0):
        raise PlyFormatError(f"{path}: {int((norm == 0).sum())} rotations (rot_0..3) are zero quaternions (first: "
                             f"vertex {int(np.argmax(norm[:, 0] == 0))})")
    rotations = rotations / norm
    with np.errstate(over="ignore"):
        scales = np.exp(stack(("scale_0", "scale_1", "scale_2")))
    if not np.all(scales <= np.finfo(np.float32).max):
        raise PlyFormatError(f"{path}: scale_0..2 hold log-scales too large for float32 after exp "
                             f"(max {float(np.max(stack(('scale_0', 'scale_1', 'scale_2')))):.3g})")
    opacities = np.exp(-np.logaddexp(0.0, -cols["opacity"]))  # sigmoid, without overflow
    colors = 0.5 + C0 * stack(("f_dc_0", "f_dc_1", "f_dc_2"))
    n_rest = sum(1 for p in cols if p.startswith("f_rest_"))
    degree = next((d for d in range(4) if num_rest_coefficients(d) == n_rest), None)
    up = _up_of(comments, path)
    if up is not None:
        means, normals, rotations = _to_frame(up, means, normals, rotations, inverse=True)
        rotations = rotations / np.linalg.norm(rotations, axis=1, keepdims=True)
    f32 = lambda a: None if a is None else np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    return PlyGaussians(f32(means), f32(scales), f32(rotations), f32(opacities), f32(colors), f32(normals), degree,
                        up, tuple(comments))


def ply_to_snapshot(g: PlyGaussians, *, space: str = "observation", frame_index: int = 0) -> Snapshot:
    """A ``Snapshot`` the studio can draw: colours clipped to [0,1], normals zero when the file had
    none (only the normal render mode uses them), visibility flags zero (a file carries none)."""
    n = len(g)
    normals = np.zeros((n, 3), np.float32) if g.normals is None else g.normals
    return Snapshot(g.means, g.scales, g.rotations, np.clip(g.colors, 0.0, 1.0).astype(np.float32), g.opacities,
                    normals, np.zeros(n, np.uint8), space=space, frame_index=frame_index)


def read_snapshot_ply(path, **kw) -> Snapshot:
    """``ply_to_snapshot(read_gaussians_ply(path))``."""
    return ply_to_snapshot(read_gaussians_ply(path), **kw)
