"""The binary FBX container read as data: a tree of named records, each with typed values.

FBX 7.x binary (what Mixamo, Maya, 3ds Max, MotionBuilder, Unity and Blender write): a 27-byte
header (the magic text and a version number), then records of ``end offset, value count, value
bytes, name`` (32-bit fields before version 7500, 64-bit from it), each followed by its values and
its children, a list closed by an all-zero record. Values are integers, floats, strings, raw bytes
and arrays (zlib-compressed or not). Nothing in the file is run; every length is checked against
the file's size before it is read, and a zlib array must unpack to exactly its declared size.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .clip import MotionFileError

MAGIC = b"Kaydara FBX Binary  \x00"
_SCALARS = {b"Y": "<h", b"C": "<?", b"I": "<i", b"F": "<f", b"D": "<d", b"L": "<q"}
_ARRAYS = {b"f": np.float32, b"d": np.float64, b"l": np.int64, b"i": np.int32, b"b": np.bool_}
MAX_DEPTH = 64


@dataclass
class FbxNode:
    """One record: its name, its values (int, float, bool, str, bytes or a numpy array) and its
    children in file order."""

    name: str
    values: list = field(default_factory=list)
    children: list[FbxNode] = field(default_factory=list)

    def find(self, name: str) -> FbxNode | None:
        """The first child named ``name``, or None."""
        return next((c for c in self.children if c.name == name), None)

    def find_all(self, name: str) -> list[FbxNode]:
        return [c for c in self.children if c.name == name]


def is_binary_fbx(data: bytes) -> bool:
    return data[:len(MAGIC)] == MAGIC


def is_ascii_fbx(data: bytes) -> bool:
    head = data[:4096].lstrip(b"\xef\xbb\xbf \t\r\n")
    return head.startswith(b"; FBX") or b"FBXHeaderExtension:" in head


def parse_fbx(path: Path, data: bytes) -> tuple[int, FbxNode]:
    """(the FBX version, e.g. 7400; a root record holding the file's top-level records)."""
    if not is_binary_fbx(data):
        raise MotionFileError(f"{path}: not a binary FBX file (it does not start with 'Kaydara FBX Binary')")
    if len(data) < 27:
        raise MotionFileError(f"{path}: truncated FBX header")
    version = struct.unpack_from("<I", data, 23)[0]
    if not 7000 <= version < 10000:
        raise MotionFileError(f"{path}: FBX version {version}; FBX 7.0 or later is read (re-export it from "
                              "a current tool)")
    wide = version >= 7500
    head = struct.Struct("<QQQB" if wide else "<IIIB")
    root = FbxNode("")
    _read_list(path, data, 27, len(data), head, root, 0)
    return version, root


def _read_list(path: Path, data: bytes, pos: int, end: int, head: struct.Struct, parent: FbxNode, depth: int) -> int:
    """Reads records from ``pos`` into ``parent.children`` until a null record or ``end``; returns
    the position after the list."""
    if depth > MAX_DEPTH:
        raise MotionFileError(f"{path}: FBX records nested deeper than {MAX_DEPTH}")
    while pos + head.size <= end:
        end_offset, count, values_len, name_len = head.unpack_from(data, pos)
        if end_offset == 0:  # the null record that closes a list
            return pos + head.size
        start = pos
        pos += head.size
        if not (pos + name_len + values_len <= end_offset <= end):
            raise MotionFileError(f"{path}: broken FBX record at byte {start} (it claims to end at byte "
                                  f"{end_offset}, past its parent's end {end})")
        name = data[pos:pos + name_len].decode("utf-8", "replace")
        pos += name_len
        node = FbxNode(name)
        values_end = pos + values_len
        for _ in range(count):
            value, pos = _read_value(path, data, pos, values_end, name)
            node.values.append(value)
        if pos != values_end:
            raise MotionFileError(f"{path}: FBX record {name!r} at byte {start}: its values take {pos - start} "
                                  f"bytes, not the {values_len} declared")
        if pos < end_offset:
            _read_list(path, data, pos, end_offset, head, node, depth + 1)
        pos = end_offset
        parent.children.append(node)
    if depth == 0:  # the file's own list ends with a null record, then a footer
        raise MotionFileError(f"{path}: truncated FBX file (it ends inside its records, at byte {len(data)})")
    return pos


def _read_value(path: Path, data: bytes, pos: int, end: int, record: str):
    if pos + 1 > end:
        raise MotionFileError(f"{path}: FBX record {record!r} is cut short")
    kind = data[pos:pos + 1]
    pos += 1
    if kind in _SCALARS:
        fmt = _SCALARS[kind]
        size = struct.calcsize(fmt)
        if pos + size > end:
            raise MotionFileError(f"{path}: FBX record {record!r} is cut short")
        return struct.unpack_from(fmt, data, pos)[0], pos + size
    if kind in (b"S", b"R"):
        if pos + 4 > end:
            raise MotionFileError(f"{path}: FBX record {record!r} is cut short")
        n = struct.unpack_from("<I", data, pos)[0]
        pos += 4
        if pos + n > end:
            raise MotionFileError(f"{path}: FBX record {record!r}: a string of {n} bytes runs past its record")
        raw = data[pos:pos + n]
        return (raw.decode("utf-8", "replace") if kind == b"S" else bytes(raw)), pos + n
    if kind in _ARRAYS:
        if pos + 12 > end:
            raise MotionFileError(f"{path}: FBX record {record!r} is cut short")
        count, encoding, size = struct.unpack_from("<III", data, pos)
        pos += 12
        dtype = np.dtype(_ARRAYS[kind])
        want = count * dtype.itemsize
        if pos + size > end:
            raise MotionFileError(f"{path}: FBX record {record!r}: an array of {size} bytes runs past its record")
        raw = data[pos:pos + size]
        if encoding == 1:
            try:
                un = zlib.decompressobj()
                raw = un.decompress(raw, want + 1)
            except zlib.error as exc:
                raise MotionFileError(f"{path}: FBX record {record!r}: a compressed array cannot be "
                                      f"unpacked ({exc})") from None
        elif encoding != 0:
            raise MotionFileError(f"{path}: FBX record {record!r}: unknown array encoding {encoding}")
        if len(raw) != want:
            raise MotionFileError(f"{path}: FBX record {record!r}: an array of {count} values holds "
                                  f"{len(raw)} bytes, not {want}")
        return np.frombuffer(raw, dtype.newbyteorder("<")).astype(dtype), pos + size
    raise MotionFileError(f"{path}: FBX record {record!r}: unknown value type {kind!r} at byte {pos - 1}")
