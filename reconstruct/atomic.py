"""Atomic file output: write to a hidden temporary file beside the target, rename it over the
target only when writing succeeded. A crash or an error leaves the previous file (or none)."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

# the process umask, read once at import (reading it means setting it, which is not thread-safe)
_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextmanager
def atomic_output(out_path, *, fsync: bool = False) -> Iterator[Path]:
    """Yields a hidden temporary path next to ``out_path`` with the same suffix (so writers that
    choose a format by suffix still do); renames it over the target when the block ends normally,
    deletes it on any error. ``fsync`` flushes the file to disk before the rename (checkpoints)."""
    out = Path(out_path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{out.stem}.", suffix=out.suffix, dir=out.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes it 0600; give the result an ordinary file's mode
    try:
        yield tmp
        if fsync:
            with open(tmp, "rb") as f:
                os.fsync(f.fileno())
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
