"""Turn a SCENE argument into a Scene: a scene folder, or ``synthetic:seed=S[,key=value...]``.

Synthetic scenes are deterministic in their configuration; the first build is cached as a scene
folder under the project cache (``$WONDERHUMAN_CACHE_DIR/scenes``) and later loads read it back.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from ..paths import cache_dir
from .scene import Scene
from .scene_io import SceneFormatError, read_scene, write_scene
from .synthetic.generator import SyntheticConfig, build_synthetic_scene

SYNTHETIC_PREFIX = "synthetic:"
DEFAULT_SCENE = "synthetic:seed=0"
_GENERATOR_VERSION = 1  # bump when the generator's output changes


def parse_synthetic_spec(spec: str) -> SyntheticConfig:
    """``synthetic:seed=3,frames=40,size=256`` -> SyntheticConfig (keys: the config's fields, plus
    the short names ``frames`` and ``size``)."""
    body = spec[len(SYNTHETIC_PREFIX):]
    aliases = {"frames": "num_frames", "size": "image_size", "azimuths": "num_eval_azimuths"}
    fields = {f.name: f.type for f in dataclasses.fields(SyntheticConfig)}
    kwargs = {}
    for item in filter(None, (s.strip() for s in body.split(","))):
        if "=" not in item:
            raise ValueError(f"scene {spec!r}: expected key=value, found {item!r}")
        key, value = (s.strip() for s in item.split("=", 1))
        key = aliases.get(key, key)
        if key not in fields:
            raise ValueError(f"scene {spec!r}: unknown key {key!r}; known: {sorted(fields) + sorted(aliases)}")
        default = getattr(SyntheticConfig(), key)
        try:
            kwargs[key] = type(default)(value)
        except ValueError as exc:
            raise ValueError(f"scene {spec!r}: {key}={value!r} is not a {type(default).__name__}") from exc
    return SyntheticConfig(**kwargs)


def synthetic_cache_key(config: SyntheticConfig) -> str:
    blob = json.dumps({"v": _GENERATOR_VERSION, **dataclasses.asdict(config)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def load_synthetic(config: SyntheticConfig, *, use_cache: bool = True, progress: bool = True) -> Scene:
    folder = cache_dir("scenes") / f"synthetic-seed{config.seed}-{synthetic_cache_key(config)}"
    if use_cache and (folder / "scene.json").is_file():
        try:
            return read_scene(folder)
        except SceneFormatError:
            pass  # a damaged cache entry is rebuilt below
    scene = build_synthetic_scene(config, progress=progress)
    if use_cache:
        write_scene(scene, folder)
    return scene


def load_scene(spec: str | Path, *, use_cache: bool = True, progress: bool = True) -> Scene:
    """A scene from a ``synthetic:...`` spec, a scene folder, a dataset spec (``zju:PATH,frames=0:300:5``,
    see reconstruct.data.loaders) or a dataset folder (layout detected). Unknown layouts raise
    SceneFormatError (naming what each layout needs)."""
    from .loaders import is_loader_spec, load_dataset

    text = str(spec)
    if text.startswith(SYNTHETIC_PREFIX):
        return load_synthetic(parse_synthetic_spec(text), use_cache=use_cache, progress=progress)
    if is_loader_spec(text):
        return load_dataset(text)
    path = Path(text)
    if not path.is_dir() and "," in text and Path(text.split(",", 1)[0]).is_dir():
        return load_dataset(text)  # a bare dataset folder with options
    if (path / "scene.json").is_file() or not path.is_dir():
        return read_scene(path)
    return load_dataset(text)
