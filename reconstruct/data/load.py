"""Turn a SCENE argument into a Scene: a scene folder, or ``synthetic:seed=S[,key=value...]``.

Synthetic scenes are deterministic in their configuration; the first build is cached as a scene
folder under the project cache (``$WONDERHUMAN_CACHE_DIR/scenes``) and later loads read it back.

Clothing models and recorded specs. ``clothing=garment`` (backs that continue the fronts) is the
default since scene-spec format 2; before, every synthetic scene had independent random backs, now
``clothing=independent``. A spec a user types is read with today's defaults; a spec RECORDED by a
run (``run.json`` "scene", the checkpoint's ``scene_spec``) must be resolved as it was when
recorded: ``canonical_scene_spec`` writes the clothing model into a spec before it is recorded, and
``recorded_scene_spec`` reads a recorded synthetic spec without a ``clothing`` key as one made
before the key existed, i.e. ``clothing=independent``. The scenes are also named apart
(``synthetic-seed0`` vs ``synthetic-seed0-garment``), so a checkpoint opened on the other scene is
refused by the name check rather than evaluated on images it was not trained on.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from ..paths import cache_dir
from .scene import Scene
from .scene_io import SceneFormatError, read_scene, write_scene
from .synthetic.garment_mesh import LOOSE_GARMENTS
from .synthetic.loose_outfit import GARMENT_VERSION
from .synthetic.generator import (
    SyntheticConfig,
    add_front_leak,
    build_synthetic_scene,
    repaint,
)

SYNTHETIC_PREFIX = "synthetic:"
DEFAULT_SCENE = "synthetic:seed=0"
_GENERATOR_VERSION = 1  # bump when the generator's output changes (for a cached configuration)
# The clothing model a synthetic spec without a ``clothing`` key meant when it was recorded by a run
# made before the key existed (scene-spec format 1); today such a spec typed by a user means the default.
LEGACY_CLOTHING = "independent"
_ALIASES = {"frames": "num_frames", "size": "image_size", "azimuths": "num_eval_azimuths"}


def _spec_items(spec: str) -> list[tuple[str, str]]:
    body = spec[len(SYNTHETIC_PREFIX):]
    items = []
    for item in filter(None, (s.strip() for s in body.split(","))):
        if "=" not in item:
            raise ValueError(f"scene {spec!r}: expected key=value, found {item!r}")
        key, value = (s.strip() for s in item.split("=", 1))
        items.append((_ALIASES.get(key, key), value))
    return items


def parse_synthetic_spec(spec: str) -> SyntheticConfig:
    """``synthetic:seed=3,frames=40,size=256,clothing=independent`` -> SyntheticConfig (keys: the
    config's fields, plus the short names ``frames``, ``size`` and ``azimuths``; ``clothing`` is
    ``garment``, ``independent`` or a loose garment: ``skirt``, ``coat``, ``dress``, ``wide_trousers``; with a
    loose garment ``fit=painted`` paints its colours on the body instead of dressing it; ``hair=long``
    paints hair worn down over the back and shoulders)."""
    fields = {f.name: f.type for f in dataclasses.fields(SyntheticConfig)}
    kwargs = {}
    for key, value in _spec_items(spec):
        if key not in fields:
            raise ValueError(f"scene {spec!r}: unknown key {key!r}; known: {sorted(fields) + sorted(_ALIASES)}")
        default = getattr(SyntheticConfig(), key)
        try:
            kwargs[key] = type(default)(value)
        except ValueError as exc:
            raise ValueError(f"scene {spec!r}: {key}={value!r} is not a {type(default).__name__}") from exc
    return SyntheticConfig(**kwargs)


def canonical_scene_spec(spec: str | Path) -> str:
    """The spec to RECORD for a run on ``spec``: a synthetic spec gets its clothing model written
    out (``synthetic:seed=0`` -> ``synthetic:seed=0,clothing=garment``), so that it still names the
    same scene when a later version changes the defaults; other specs are returned as they are."""
    text = str(spec)
    if not text.startswith(SYNTHETIC_PREFIX) or any(k == "clothing" for k, _ in _spec_items(text)):
        return text
    clothing = parse_synthetic_spec(text).clothing
    sep = "" if text.endswith((":", ",")) else ","
    return f"{text}{sep}clothing={clothing}"


def recorded_scene_spec(spec: str | Path) -> str:
    """The spec to LOAD for a spec recorded by a run (``run.json`` "scene", the checkpoint's
    ``scene_spec``): a synthetic spec without a ``clothing`` key was recorded before clothing models
    existed, when every synthetic scene had independent backs, and resolves to those."""
    text = str(spec)
    if not text.startswith(SYNTHETIC_PREFIX) or any(k == "clothing" for k, _ in _spec_items(text)):
        return text
    sep = "" if text.endswith((":", ",")) else ","
    return f"{text}{sep}clothing={LEGACY_CLOTHING}"


def synthetic_cache_key(config: SyntheticConfig) -> str:
    """A hash of the configuration. The original (independent) clothes keep the key they had before
    the ``clothing`` field existed, so their cache folders are found again (the images are the
    same; the front-leak information they lack is added on load). Loose garments
    (``clothing=skirt|coat|dress|wide_trousers``) are in the key through ``clothing`` and add the
    garment version (loose_outfit.GARMENT_VERSION)."""
    d = dataclasses.asdict(config)
    if d["fit"] == "loose":  # the default fit keeps the keys made before the field existed
        del d["fit"]
    if d["hair"] == "drawn":  # so does the default hair
        del d["hair"]
    if d["clothing"] == "independent":
        del d["clothing"]
    elif d["clothing"] in LOOSE_GARMENTS:  # loose garments: their geometry/skinning/colour version too
        d["garment_version"] = GARMENT_VERSION
    blob = json.dumps({"v": _GENERATOR_VERSION, **d}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _has_front_leak(scene: Scene) -> bool:
    return "front_leak" in scene.meta and all(v.front_leak is not None for v in scene.eval_views if not v.seen)


def load_synthetic(config: SyntheticConfig, *, use_cache: bool = True, progress: bool = True) -> Scene:
    folder = cache_dir("scenes") / f"synthetic-seed{config.seed}-{synthetic_cache_key(config)}"
    if use_cache and (folder / "scene.json").is_file():
        try:
            scene = read_scene(folder)
        except SceneFormatError:
            scene = None  # a damaged cache entry is rebuilt below
        if scene is not None and _has_front_leak(scene):
            return scene
        if scene is not None:
            # written before scenes carried front-leak information: add it when the cached texture is
            # what the generator paints today (else rebuild)
            painted = repaint(config)
            texture = scene.meta.get("texture")
            if texture is not None and getattr(texture, "shape", None) == painted.texture.shape \
                    and (texture[..., :3] == painted.texture).all():
                add_front_leak(scene, painted, config)
                write_scene(scene, folder)
                return scene
    scene = build_synthetic_scene(config, progress=progress)
    if use_cache:
        write_scene(scene, folder)
    return scene


def load_scene(spec: str | Path, *, use_cache: bool = True, progress: bool = True) -> Scene:
    """A scene from a ``synthetic:...`` spec, a scene folder, a dataset spec (``zju:PATH,frames=0:300:5``,
    see reconstruct.data.loaders) or a dataset folder (layout detected). Unknown layouts raise
    SceneFormatError (naming what each layout needs). A spec recorded by a run is loaded with
    ``load_scene(recorded_scene_spec(spec))``."""
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
