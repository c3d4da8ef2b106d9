"""The edits of a run folder: ``RUN/edits/edits.json`` plus one ``.npz`` per edit (its texel mask;
a redo's colour offsets; a lock's model parameters), read with ``np.load(allow_pickle=False)``.

Written atomically: each new ``.npz`` first (entries never change once written), then the JSON --
the commit point -- then ``.npz`` files no entry names any more are removed. Reading checks
everything and raises ``EditsError`` naming the file; it never writes, so a malformed file leaves
the run as it is.

edits.json::

    {"format": 1, "num_gaussians": 9832, "next_id": 4,
     "applied": [{"id": 1, "op": "erase", "params": {}, "file": "e0001.npz", "count": 52,
                  "label": "rect=100,80,140,120@front", "created": "2026-11-24T00:30:00Z"}, ...],
     "undone": [...]}          # the redo stack, the most recently undone last
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_output
from .edit_list import EditEntry, EditList
from .ops import Lock, Redo, op_from_params

EDITS_DIR = "edits"
EDITS_NAME = "edits.json"
FORMAT = 1
PARAM_PREFIX = "param:"


class EditsError(ValueError):
    pass


@dataclass
class StoredEdits:
    applied: EditList
    undone: list[EditEntry] = field(default_factory=list)
    next_id: int = 1


def edits_path(run_dir) -> Path:
    return Path(run_dir) / EDITS_DIR / EDITS_NAME


def entry_file(entry: EditEntry) -> str:
    return f"e{entry.id:04d}.npz"


def _write_npz(path: Path, entry: EditEntry) -> None:
    arrays = {"mask": np.asarray(entry.mask, bool)}
    if entry.color_offset is not None:
        arrays["color_offset"] = np.asarray(entry.color_offset, np.float32)
    for k, v in (entry.lock_params or {}).items():
        arrays[PARAM_PREFIX + k] = np.asarray(v, np.float32)
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)


def _entry_json(e: EditEntry) -> dict:
    return {"id": e.id, "op": e.op.name, "params": e.op.params(), "file": entry_file(e), "count": e.count,
            "label": e.label, "created": e.created}


def save_edits(run_dir, applied: EditList, undone: list[EditEntry] = (), next_id: int | None = None) -> Path:
    """Writes the run's edits (atomically; see the module doc). Returns the JSON's path."""
    path = edits_path(run_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    entries = list(applied) + list(undone)
    ids = [e.id for e in entries]
    if len(set(ids)) != len(ids):
        raise ValueError(f"edit ids must be unique, found {ids}")
    for e in entries:
        f = path.parent / entry_file(e)
        if not f.is_file() or e._runtime.get("written_to") != str(f):
            _write_npz(f, e)
            e._runtime["written_to"] = str(f)
    doc = {"format": FORMAT, "num_gaussians": applied.num_gaussians,
           "next_id": int(next_id if next_id is not None else max(ids, default=0) + 1),
           "applied": [_entry_json(e) for e in applied], "undone": [_entry_json(e) for e in undone]}
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1))
    keep = {entry_file(e) for e in entries}
    for f in path.parent.glob("e*.npz"):
        if f.name not in keep:
            f.unlink(missing_ok=True)
    return path


def _fail(path: Path, why: str):
    raise EditsError(f"{path}: {why}; the run is left as it is (fix or move the edits folder away to go on "
                     f"without edits)")


def _read_entry(path: Path, d, num_gaussians: int, model_params: dict[str, tuple] | None) -> EditEntry:
    if not isinstance(d, dict):
        _fail(path, f"an entry must be an object, found {type(d).__name__}")
    for key, kind in (("id", int), ("op", str), ("file", str)):
        if not isinstance(d.get(key), kind) or isinstance(d.get(key), bool):
            _fail(path, f"entry {d.get('id', '?')}: '{key}' must be {kind.__name__}, found {d.get(key)!r}")
    try:
        op = op_from_params(d["op"], d.get("params", {}))
    except (TypeError, ValueError) as exc:
        _fail(path, f"entry {d['id']}: {exc}")
    name = d["file"]
    if "/" in name or "\\" in name or name.startswith(".") or not name.endswith(".npz"):
        _fail(path, f"entry {d['id']}: 'file' must be a .npz name in the edits folder, found {name!r}")
    npz = path.parent / name
    if not npz.is_file():
        _fail(path, f"entry {d['id']}: its mask file {npz} is missing")
    try:
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        _fail(path, f"entry {d['id']}: {npz.name} is not a readable .npz without pickled objects ({exc})")
    mask = arrays.get("mask")
    if mask is None or mask.dtype != np.bool_ or mask.shape != (num_gaussians,):
        _fail(path, f"entry {d['id']}: {npz.name} needs 'mask', a bool array of {num_gaussians} texels"
                    + ("" if mask is None else f" (found {mask.dtype} {mask.shape})"))
    offset = arrays.get("color_offset")
    if isinstance(op, Redo):
        if offset is None or offset.shape != (int(mask.sum()), 3) or not np.isfinite(offset).all():
            _fail(path, f"entry {d['id']}: a redo needs finite 'color_offset' of shape ({int(mask.sum())}, 3)")
    params = {k[len(PARAM_PREFIX):]: v for k, v in arrays.items() if k.startswith(PARAM_PREFIX)}
    if isinstance(op, Lock):
        if not params:
            _fail(path, f"entry {d['id']}: a lock needs the model's parameters ('{PARAM_PREFIX}NAME' arrays)")
        if model_params is not None:
            for k, shape in model_params.items():
                if k.startswith("pose_encoder.") and not any(p.startswith("pose_encoder.") for p in params):
                    continue
                if k not in params or tuple(params[k].shape) != shape:
                    _fail(path, f"entry {d['id']}: the lock's parameter {k} is missing or has another shape "
                                f"than this model's {shape}")
            extra = set(params) - set(model_params)
            if extra:
                _fail(path, f"entry {d['id']}: the lock holds parameters this model has not: {sorted(extra)[:4]}")
    label, created = d.get("label", ""), d.get("created", "")
    if not isinstance(label, str) or not isinstance(created, str):
        _fail(path, f"entry {d['id']}: 'label' and 'created' must be strings")
    entry = EditEntry(d["id"], op, mask, label, created, offset.astype(np.float32) if isinstance(op, Redo) else None,
                      params if isinstance(op, Lock) else None)
    entry._runtime["written_to"] = str(npz)
    return entry


def load_edits(run_dir, num_gaussians: int, model=None) -> StoredEdits:
    """The run's edits (an empty list when it has none). ``model``: checks that locks fit it."""
    path = edits_path(run_dir)
    if not path.exists():
        return StoredEdits(EditList((), num_gaussians))
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        _fail(path, f"not readable as JSON ({exc})")
    if not isinstance(doc, dict):
        _fail(path, "expected a JSON object")
    if doc.get("format") != FORMAT:
        _fail(path, f"unknown format {doc.get('format')!r} (this version reads {FORMAT})")
    if doc.get("num_gaussians") not in (None, num_gaussians):
        _fail(path, f"made for an avatar of {doc.get('num_gaussians')} Gaussians; this run's has {num_gaussians}")
    for key in ("applied", "undone"):
        if not isinstance(doc.get(key, []), list):
            _fail(path, f"'{key}' must be a list")
    shapes = None if model is None else {k: tuple(p.shape) for k, p in model.named_parameters()}
    applied = [_read_entry(path, d, num_gaussians, shapes) for d in doc.get("applied", [])]
    undone = [_read_entry(path, d, num_gaussians, shapes) for d in doc.get("undone", [])]
    ids = [e.id for e in applied + undone]
    if len(set(ids)) != len(ids):
        _fail(path, f"edit ids repeat: {ids}")
    next_id = doc.get("next_id", max(ids, default=0) + 1)
    if not isinstance(next_id, int) or next_id <= max(ids, default=0):
        _fail(path, f"'next_id' must be an integer above every edit id, found {next_id!r}")
    return StoredEdits(EditList(applied, num_gaussians), undone, next_id)
