"""Reading pickled data that other people share (dataset ``.npy`` files, SMPL ``.pkl`` files)
without running code from it.

A pickle is a small program: its ``GLOBAL`` / ``STACK_GLOBAL`` opcodes name any importable callable
(``os.system``, ``builtins.open`` ...) and ``REDUCE`` calls it. ``np.load(..., allow_pickle=True)``
and ``pickle.load`` therefore run whatever a crafted file asks for. ``RestrictedUnpickler`` answers
every global a file names from a fixed table of plain-data constructors (``PLAIN_DATA_GLOBALS``:
the builtin containers and numbers, ``collections.OrderedDict``, and the handful of numpy callables
numpy's own pickling emits for arrays, dtypes and scalars, in both the numpy 1 ``numpy.core`` and the
numpy 2 ``numpy._core`` spellings). Nothing is imported by name: an allowed global resolves to an
object this module already holds, so an unknown name cannot even trigger an import. Any other
global raises ``RefusedGlobalError`` naming the file and ``module.name``.

``load_npy`` / ``load_npy_object`` read ``.npy`` files: the header is parsed with
``numpy.lib.format`` (a Python literal, read with ``ast.literal_eval`` there), arrays of plain
dtypes are read by ``np.load(allow_pickle=False)``, and object arrays (whose payload is a pickle)
through the restricted unpickler. Every failure is a ``SafeLoadError`` that says which file, what
was expected and what was found (empty or truncated file, wrong magic, corrupt pickle, refused
global).

Subclasses extend the table for formats that need more (``reconstruct.body.smpl_backend``'s SMPL
model reader admits scipy.sparse matrices and a stand-in for chumpy's classes) by overriding
``resolve``.
"""

from __future__ import annotations

import _compat_pickle
import ast
import collections
import io
import os
import pickle
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import numpy.lib.format as npy_format

NPY_MAGIC = b"\x93NUMPY"
PLAIN_DATA = ("plain data only: dict, list, tuple, set, str, bytes, numbers, None and numpy arrays, dtypes "
              "and scalars")


class SafeLoadError(ValueError):
    """A shared file that cannot be read as plain data. The message names the file, what was
    expected and what was found; ``path`` holds the file."""

    def __init__(self, path: str | os.PathLike | None, message: str) -> None:
        self.path = None if path is None else str(path)
        super().__init__(f"{path}: {message}" if path is not None else message)


class RefusedGlobalError(SafeLoadError, pickle.UnpicklingError):
    """The pickle names a global outside the allow-list (``module.name`` in ``global_name``): loading
    it would construct or call something other than plain data, e.g. run a command."""

    def __init__(self, path, module: str, name: str, allowed: str) -> None:
        self.global_name = f"{module}.{name}"
        super().__init__(path, f"refusing to load {self.global_name}: the file may hold {allowed}; this global "
                               f"could run code (a crafted file, or one written by a program that pickles its own "
                               f"classes)")


# ----- the allow-list ---------------------------------------------------------------------------
def _numpy_core_module(name: str):
    """``numpy._core.<name>`` on numpy 2, ``numpy.core.<name>`` on numpy 1 (no deprecation warning)."""
    import importlib

    try:
        return importlib.import_module(f"numpy._core.{name}")
    except ImportError:  # numpy 1.x
        return importlib.import_module(f"numpy.core.{name}")


def _plain_data_globals() -> dict[tuple[str, str], Any]:
    import builtins

    table: dict[tuple[str, str], Any] = {
        ("builtins", n): getattr(builtins, n)
        for n in ("dict", "list", "tuple", "set", "frozenset", "str", "bytes", "bytearray", "int", "float", "bool",
                  "complex", "slice")
    }
    table[("collections", "OrderedDict")] = collections.OrderedDict
    # protocol <= 2 pickles written by Python 3 spell bytes as _codecs.encode(text, 'latin1')
    import _codecs

    table[("_codecs", "encode")] = _codecs.encode
    multiarray, numeric = _numpy_core_module("multiarray"), _numpy_core_module("numeric")
    for core in ("numpy.core", "numpy._core"):
        table[(f"{core}.multiarray", "_reconstruct")] = multiarray._reconstruct  # ndarray.__reduce__
        table[(f"{core}.multiarray", "scalar")] = multiarray.scalar  # numpy scalars
        if hasattr(numeric, "_frombuffer"):  # ndarray.__reduce_ex__ with protocol 5
            table[(f"{core}.numeric", "_frombuffer")] = numeric._frombuffer
    table[("numpy", "ndarray")] = np.ndarray
    table[("numpy", "dtype")] = np.dtype
    return table


PLAIN_DATA_GLOBALS: Mapping[tuple[str, str], Any] = _plain_data_globals()


def python3_name(module: str, name: str) -> tuple[str, str]:
    """Python 2 spellings (``__builtin__.unicode``, ``copy_reg._reconstructor``) in Python 3's, as the
    standard unpickler's ``fix_imports`` maps them."""
    if (module, name) in _compat_pickle.NAME_MAPPING:
        return _compat_pickle.NAME_MAPPING[(module, name)]
    return _compat_pickle.IMPORT_MAPPING.get(module, module), name


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that builds only plain data (see the module docstring).

    ``source`` names the file in error messages. ``encoding="latin1"`` reads Python 2 pickles of
    numpy arrays (numpy's own advice) and is the same as ASCII for everything ASCII can read.
    Subclasses admit more by overriding ``resolve`` (return None to refuse) and ``allowed``
    (the words the refusal uses for what the file may hold)."""

    allowed: str = PLAIN_DATA

    def __init__(self, file, *, source: str | os.PathLike | None = None, encoding: str = "latin1") -> None:
        super().__init__(file, encoding=encoding, fix_imports=True)
        self.source = source

    def resolve(self, module: str, name: str) -> Any | None:
        """The object a global stands for, or None to refuse it; ``module``/``name`` already in
        Python 3 spelling."""
        return PLAIN_DATA_GLOBALS.get((module, name))

    def find_class(self, module: str, name: str) -> Any:
        obj = self.resolve(*python3_name(module, name))
        if obj is None:
            raise RefusedGlobalError(self.source, module, name, self.allowed)
        return obj

    def persistent_load(self, pid):  # noqa: D401 - pickle API
        raise SafeLoadError(self.source, f"refusing a persistent id ({str(pid)[:40]!r}): {self.allowed}")


def restricted_loads(data: bytes, *, source: str | os.PathLike | None = None,
                     unpickler: Callable[..., RestrictedUnpickler] = RestrictedUnpickler,
                     what: str = "pickled data") -> Any:
    """Unpickle ``data`` with ``unpickler`` (default: plain data only). Any failure becomes a
    ``SafeLoadError`` naming ``source``: a refused global, an empty or truncated stream, or bytes
    that are not a pickle."""
    if not data:
        raise SafeLoadError(source, f"expected {what}, found an empty file")
    try:
        return unpickler(io.BytesIO(data), source=source).load()
    except SafeLoadError:
        raise
    except EOFError as exc:
        raise SafeLoadError(source, f"expected {what}, found a truncated pickle stream ({len(data)} bytes; "
                                    f"{exc or 'ran out of input'})") from exc
    except pickle.UnpicklingError as exc:
        if "truncated" not in str(exc):
            raise SafeLoadError(source, f"expected {what}, found bytes that are not a valid pickle of it "
                                        f"(UnpicklingError: {_first_line(exc)})") from exc
        raise SafeLoadError(source, f"expected {what}, found a truncated pickle stream ({len(data)} bytes)") from exc
    except RecursionError as exc:
        raise SafeLoadError(source, f"expected {what}, found nesting too deep to read") from exc
    except Exception as exc:  # pickle.UnpicklingError, ValueError, TypeError, KeyError, MemoryError ...
        raise SafeLoadError(source, f"expected {what}, found bytes that are not a valid pickle of it "
                                    f"({type(exc).__name__}: {_first_line(exc)})") from exc


def _first_line(exc: BaseException) -> str:
    text = str(exc)
    return text.splitlines()[0][:200] if text else "no details"


# ----- .npy files -------------------------------------------------------------------------------
@dataclass(frozen=True)
class NpyHeader:
    """What a .npy header says: format version, array shape, memory order, dtype, and where the
    data starts (bytes from the beginning of the file)."""

    version: tuple[int, int]
    shape: tuple[int, ...]
    fortran_order: bool
    dtype: np.dtype
    data_offset: int


def _describe_start(head: bytes) -> str:
    if head.startswith(b"PK"):
        return f"a zip archive (an .npz file?): it starts with {head[:8]!r}"
    if head[:1] == b"\x80":
        return f"a bare pickle stream (np.load would unpickle it; it is not read here): it starts with {head[:8]!r}"
    return f"it starts with {head[:8]!r}"


def read_npy_header(f, path: str | os.PathLike) -> NpyHeader:
    """Parse the header of the open .npy file ``f`` (at its start); ``SafeLoadError`` for a file that
    is empty, not a .npy file, of an unknown version, or whose header is truncated or malformed."""
    head = f.read(len(NPY_MAGIC) + 2)
    if not head:
        raise SafeLoadError(path, "expected a .npy file, found an empty file")
    if head[: len(NPY_MAGIC)] != NPY_MAGIC:
        if NPY_MAGIC.startswith(head):
            raise SafeLoadError(path, f"expected a .npy file, found a truncated one ({len(head)} bytes)")
        raise SafeLoadError(path, f"expected a .npy file (starting with {NPY_MAGIC!r}), found {_describe_start(head)}")
    if len(head) < len(NPY_MAGIC) + 2:
        raise SafeLoadError(path, f"expected a .npy file, found a truncated one ({len(head)} bytes: no version)")
    version = (head[6], head[7])
    f.seek(0)
    try:
        npy_format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = npy_format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = npy_format.read_array_header_2_0(f)
        elif version == (3, 0):
            shape, fortran, dtype = _read_header_3_0(f)
        else:
            raise SafeLoadError(path, f"expected a .npy file of format version 1.0, 2.0 or 3.0, found version "
                                      f"{version[0]}.{version[1]}")
    except SafeLoadError:
        raise
    except Exception as exc:  # numpy raises ValueError for EOF and malformed headers
        raise SafeLoadError(path, f"expected a .npy header (a Python dict with 'descr', 'fortran_order' and "
                                  f"'shape'), found a truncated or malformed one ({_first_line(exc)})") from exc
    return NpyHeader(version, tuple(int(n) for n in shape), bool(fortran), np.dtype(dtype), f.tell())


def _read_header_3_0(f) -> tuple[tuple[int, ...], bool, np.dtype]:
    """Version 3.0 (a UTF-8 header, written only for non-latin-1 field names): numpy has no public
    reader for it, so read the length and the literal here the way numpy does."""
    raw = f.read(4)
    if len(raw) != 4:
        raise ValueError("EOF in the header length")
    (length,) = struct.unpack("<I", raw)
    if length > 10000:
        raise ValueError(f"header of {length} bytes is larger than the 10000 numpy accepts")
    text = f.read(length)
    if len(text) != length:
        raise ValueError(f"EOF in the header: expected {length} bytes, found {len(text)}")
    d = ast.literal_eval(text.decode("utf8"))
    if not isinstance(d, dict) or set(d) != {"descr", "fortran_order", "shape"}:
        raise ValueError(f"header is not a dict with keys descr, fortran_order, shape: {text[:80]!r}")
    shape = d["shape"]
    if not isinstance(shape, tuple) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise ValueError(f"shape is not a tuple of sizes: {shape!r}")
    if not isinstance(d["fortran_order"], bool):
        raise ValueError(f"fortran_order is not a bool: {d['fortran_order']!r}")
    return shape, d["fortran_order"], npy_format.descr_to_dtype(d["descr"])


def load_npy(path: str | os.PathLike) -> np.ndarray:
    """The array in a .npy file, as ``np.load`` returns it, without running code: plain dtypes through
    ``np.load(allow_pickle=False)``; object arrays (pickled) through ``RestrictedUnpickler``."""
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            header = read_npy_header(f, path)
            if header.dtype.hasobject:
                payload = f.read()
            else:
                payload = None
    except OSError as exc:
        raise SafeLoadError(path, f"cannot be opened: {exc.strerror or exc}") from exc
    if payload is None:
        count = int(np.prod(header.shape, dtype=np.int64))
        need = count * header.dtype.itemsize
        have = size - header.data_offset
        if have < need:
            raise SafeLoadError(path, f"expected {need} bytes of {header.dtype} data for shape {header.shape} after "
                                      f"the header, found {have}: the file is truncated")
        try:
            return np.load(path, allow_pickle=False)
        except Exception as exc:
            raise SafeLoadError(path, f"cannot be read as a .npy array: {_first_line(exc)}") from exc
    what = f"a pickled numpy object array of shape {header.shape}"
    value = restricted_loads(payload, source=path, what=what)
    if not isinstance(value, np.ndarray):
        raise SafeLoadError(path, f"expected {what}, found a pickled {type(value).__name__}")
    if value.shape != header.shape:
        raise SafeLoadError(path, f"expected {what} (the header's shape), found one of shape {value.shape}")
    return value


def load_npy_object(path: str | os.PathLike) -> Any:
    """What ``np.save(path, obj)`` stored: for a 0-d object array (a saved dict, list ...) the object
    itself, as ``np.load(path, allow_pickle=True).item()`` gives it; otherwise the array, as
    ``np.load`` gives it. Never runs code from the file (see ``load_npy``)."""
    arr = load_npy(path)
    if arr.dtype == object and arr.shape == ():
        return arr.item()
    return arr
