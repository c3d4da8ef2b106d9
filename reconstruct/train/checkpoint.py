"""Checkpoints: written to a temporary file in the same folder, fsynced, then renamed over the old
one, so a crash at any moment leaves either the previous or the new checkpoint, never a torn one.
A write that fails (disk full, read-only folder, file size limit) raises ``CheckpointWriteError``
naming the file and the cause, and leaves the previous checkpoint as it was."""

from __future__ import annotations

import io
import os
import re
from pathlib import Path

import torch

from ..atomic import atomic_output

FORMAT = "wonderhuman-checkpoint"
VERSION = 1


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
    (a run folder has one training process: app.train_cmd.RunLock)."""
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


def load_checkpoint(path: str | os.PathLike, map_location="cpu") -> dict:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint file")
    try:
        state = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a WonderHuman checkpoint (format {state.get('format') if isinstance(state, dict) else type(state).__name__!r})")
    if state.get("version") != VERSION:
        raise CheckpointError(f"{path}: checkpoint version {state.get('version')} is not supported (expected {VERSION})")
    return state
