"""GLSL sources shipped with the package.

``load("splat.vert")`` returns the text of the file of that name next to this module. Names
are plain file names (no directories); a missing file raises ``FileNotFoundError`` listing the
shaders that do exist.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

_DIR = Path(__file__).resolve().parent


def available() -> list[str]:
    """Names of the shader files in this package."""
    return sorted(p.name for p in _DIR.iterdir() if p.suffix in {".vert", ".frag", ".geom", ".glsl", ".comp"})


@lru_cache(maxsize=None)
def load(name: str) -> str:
    """Source text of the shader file ``name`` (e.g. ``"splat.vert"``)."""
    if not name or Path(name).name != name:
        raise ValueError(f"shader name must be a plain file name, found {name!r}")
    path = _DIR / name
    if not path.is_file():
        raise FileNotFoundError(f"no shader {name!r} in {_DIR}; available: {available()}")
    return path.read_text(encoding="utf-8")
