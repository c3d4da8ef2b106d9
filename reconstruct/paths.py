"""Where the project keeps its caches (compiled kernels, generated scenes)."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir(*parts: str) -> Path:
    """``$WONDERHUMAN_CACHE_DIR`` (default ``~/.cache/wonderhuman``) joined with ``parts``, created."""
    root = Path(os.environ.get("WONDERHUMAN_CACHE_DIR", str(Path.home() / ".cache" / "wonderhuman")))
    path = root.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path
