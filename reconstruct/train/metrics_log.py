"""``RUN/metrics.jsonl``: one JSON object per line, each written with a single ``write`` call so a
killed run never leaves a torn line in the middle (a torn last line is skipped when reading)."""

from __future__ import annotations

import json
import os
from pathlib import Path


class MetricsLog:
    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)

    def append(self, record: dict) -> None:
        line = (json.dumps(record, separators=(",", ":")) + "\n").encode()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            start = os.fstat(fd).st_size
            written = os.write(fd, line)
            if written != len(line):  # a short write (disk nearly full): take the partial line back
                os.ftruncate(fd, start)
                raise OSError(28, f"{self.path}: metrics record not written (short write, {written} of "
                              f"{len(line)} bytes)")
        finally:
            os.close(fd)

    def read(self, kind: str | None = None) -> list[dict]:
        if not self.path.is_file():
            return []
        out = []
        for line in self.path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line torn by a kill
            if kind is None or rec.get("kind") == kind:
                out.append(rec)
        return out

    def truncate_after(self, step: int) -> None:
        """Drop records newer than ``step`` (a resumed run repeats the steps after its checkpoint)."""
        keep = [r for r in self.read() if r.get("step", 0) <= step]
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in keep))
        os.replace(tmp, self.path)
