"""Checkpoints: tensors and plain data only, read without running code, written atomically.

A checkpoint is a dict of tensors, numbers, strings, lists, tuples and dicts (the RNG states
included), saved with ``torch.save`` and read back with ``torch.load(weights_only=True)``: its
unpickler admits those types and nothing else, so a checkpoint from someone else cannot execute
code when a run folder is opened (``--run``, ``eval``, ``export``, ``train`` resuming).

Writing: serialised in memory, written to a temporary file in the same folder, fsynced, then
renamed over the old one, so a crash at any moment leaves either the previous or the new
checkpoint, never a torn one. A write that fails (disk full, read-only folder, file size limit)
raises ``CheckpointWriteError`` naming the file and the cause, and leaves the previous one as it was.

An avatar with a garment layer (``AvatarConfig.garment_layer``) keeps the layer's geometry under
``avatar.garment_layer`` as plain tensors and numbers (``GarmentLayer.to_state``: positions,
normals, tangents, skinning weights, spacing, grid shape, the volume hint's numbers); the trainer
rebuilds the model with it before loading the rest (``garment_layer_of``). Checkpoints without it
(every one written before the layer existed) load as avatars without a layer.

Version 1 checkpoints (written before this format) were read with full unpickling. They are
refused with a message saying how to convert them once (``migrate_checkpoint``, the ``migrate``
command): one that reads as data as it is, one holding other Python objects only with ``--trust``.
"""

from __future__ import annotations

import io
import os
import pickle
import re
from pathlib import Path

import torch

from ..atomic import atomic_output
from ..avatar.garment_layer import GarmentLayer

FORMAT = "wonderhuman-checkpoint"
VERSION = 2
CHECKPOINT_NAME = "checkpoint.pt"
STAGE1_CHECKPOINT_NAME = "checkpoint_stage1.pt"


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: names the file and the problem."""


class CheckpointWriteError(OSError, RuntimeError):
    """A checkpoint could not be written (the previous one is kept); ``errno`` is the cause's."""


def save_checkpoint(state: dict, path: str | os.PathLike) -> Path:
    """Write ``state`` atomically. It is serialised in memory first and written with one plain file
    write, so that a full disk or a read-only folder reports its own errno (torch.save into a file
    reports an error of its zip writer, "unexpected pos 768 vs 662", instead)."""
    path = Path(path)
    buffer = io.BytesIO()
    torch.save({"format": FORMAT, "version": VERSION, **state}, buffer)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path, fsync=True) as tmp, open(tmp, "wb") as f:
            f.write(buffer.getbuffer())
    except OSError as exc:
        message = f"{path}: checkpoint not written ({exc.strerror or exc}); the previous checkpoint, if any, is kept"
        raise (CheckpointWriteError(exc.errno, message) if exc.errno else CheckpointWriteError(message)) from exc
    _remove_stale_temporaries(path)
    return path


def _remove_stale_temporaries(path: Path) -> None:
    """Delete the hidden temporary files of earlier writes of ``path`` (atomic_output's
    ``.<stem>.<8 random characters><suffix>``) that a process killed mid-write left behind: without
    this, every SIGKILL during a checkpoint write left one more checkpoint-sized file in the run
    folder. Only called after a successful write, when no other write of this path is in flight
    (a run folder has one training process: reconstruct.run_folder.RunLock)."""
    pattern = re.compile(rf"\.{re.escape(path.stem)}\.[A-Za-z0-9_]{{8}}{re.escape(path.suffix)}")
    try:
        stale = [p for p in path.parent.iterdir() if pattern.fullmatch(p.name)]
    except OSError:
        return
    for p in stale:
        try:
            p.unlink()
        except OSError:
            pass


def _read(path: Path, map_location, *, trust: bool) -> dict:
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint file")
    try:
        state = torch.load(path, map_location=map_location, weights_only=not trust)
    except pickle.UnpicklingError as exc:
        refused, detail = _weights_only_failure(exc)
        if refused:
            raise CheckpointError(
                f"{path}: refused: it holds Python objects other than tensors and plain data, and loading those "
                f"could run code ({detail}). A checkpoint written by an earlier version of this program can be "
                f"converted once, if you trust where it came from: wonderhuman-studio migrate {path.parent} "
                f"--trust") from exc
        raise CheckpointError(f"{path}: not a readable checkpoint ({detail})") from exc
    except Exception as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {_first_line(exc)})") from exc
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(f"{path}: not a WonderHuman checkpoint (format {found!r})")
    return state


def _weights_only_failure(exc: Exception) -> tuple[bool, str]:
    """(whether the data-only unpickler refused a Python global, the line that says what) of a
    ``torch.load(weights_only=True)`` failure; torch wraps both refusals and corrupt bytes in one
    long UnpicklingError."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    for ln in lines:
        m = re.search(r"GLOBAL (\S+)", ln)
        if m:
            return True, f"the global {m.group(1)}"
    text = str(exc)
    if "WeightsUnpickler error:" in text:
        detail = text.split("WeightsUnpickler error:", 1)[1].strip().splitlines()
        return False, detail[0].strip() if detail else "corrupt data"
    return False, lines[-1] if lines else type(exc).__name__


def _first_line(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def load_checkpoint(path: str | os.PathLike, map_location="cpu") -> dict:
    """A checkpoint's state, read as data (``weights_only``): CheckpointError for anything else."""
    path = Path(path)
    state = _read(path, map_location, trust=False)
    if state.get("version") == 1:
        raise CheckpointError(f"{path}: written by an earlier version of this program (checkpoint format 1); "
                              f"convert it once with: wonderhuman-studio migrate {path.parent}")
    if state.get("version") != VERSION:
        raise CheckpointError(f"{path}: checkpoint version {state.get('version')} is not supported (expected {VERSION})")
    return state


def garment_layer_of(state: dict, source: str = "checkpoint", num_joints: int | None = None) -> GarmentLayer | None:
    """The garment layer a checkpoint's avatar was trained with (None: none, as in every checkpoint
    written before the layer existed); CheckpointError naming ``source`` when it is malformed."""
    avatar = state.get("avatar")
    saved = avatar.get("garment_layer") if isinstance(avatar, dict) else None
    if saved is None:
        return None
    try:
        return GarmentLayer.from_state(saved, source, num_joints)
    except ValueError as exc:
        raise CheckpointError(str(exc)) from exc


def migrate_checkpoint(path: str | os.PathLike, *, trust: bool = False) -> bool:
    """Convert a version-1 checkpoint to the current format in place (written atomically). One
    that reads as data is converted as it is; one that holds other Python objects needs full
    unpickling, which can run code: ``trust`` must say the user trusts the file. Returns False
    when the file is already current."""
    path = Path(path)
    try:
        state = _read(path, "cpu", trust=False)
    except CheckpointError:
        if not trust:
            raise
        state = _read(path, "cpu", trust=True)
    if state.get("version") == VERSION:
        return False
    if state.get("version") != 1:
        raise CheckpointError(f"{path}: checkpoint version {state.get('version')} cannot be migrated")
    save_checkpoint(upgrade_v1(state), path)
    return True


def plain_scalars(d: dict) -> dict:
    """The entries of ``d`` that are numbers, strings or booleans, as plain Python values (numpy
    scalars would not pass the data-only reader)."""
    out = {}
    for k, v in d.items():
        if isinstance(v, bool):
            out[str(k)] = bool(v)
        elif isinstance(v, int):
            out[str(k)] = int(v)
        elif isinstance(v, float):
            out[str(k)] = float(v)
        elif isinstance(v, str):
            out[str(k)] = str(v)
    return out


def upgrade_v1(old: dict) -> dict:
    """The version-2 layout of a version-1 checkpoint state (TrainingSession / Stage2Session)."""
    st2 = old.get("stage2")
    stage = int(old.get("stage", 1))
    step = int(old["step"])
    new = {
        "stage": stage,
        "step": step,
        "elapsed": float(old["elapsed"]),
        "config": old["config"],
        "scene_spec": old.get("scene_spec"),
        "scene_name": old.get("scene_name"),
        "avatar": {"model": old["model"], "pose_delta": old["pose_delta"], "seen": old["seen"],
                   "trusted_seen": st2.get("trusted_seen") if st2 else None},
        "optimizer": old["optimizer"],
        "pose_optimizer": old.get("pose_optimizer"),
        "epoch_order": [int(i) for i in old.get("epoch_order", [])],
        "rng": {"numpy": old["rng"]["numpy"], "torch": old["rng"]["torch"], "python": old["rng"]["python"]},
        "latest": plain_scalars(dict(old.get("latest", {}))),
        "nonfinite_skipped": int(old.get("nonfinite_skipped", 0)),
        "restored_states": int(old.get("restored_states", 0)),
    }
    if stage == 1:
        new.update(stage_step=step, stage_elapsed=float(old["elapsed"]), stage_starts={"1": 0},
                   kind_counts={"given": step}, plan={"settings": old["config"]})
    else:
        new.update(stage_step=int(st2["step"]), stage_elapsed=float(st2["elapsed"]),
                   stage_starts={"1": 0, "2": int(st2["stage1_step"])},
                   kind_counts={str(k): int(v) for k, v in st2["kind_counts"].items()},
                   plan={"settings": st2["config"], "pseudo_colors": st2["pseudo_colors"],
                         "canonical_reference": st2["canonical_reference"], "spaces": st2["spaces"],
                         "sds_note": st2.get("sds_note")})
    return new
