"""Reliability of runs: a checkpoint write that fails (disk full, read-only folder, file size
limit) fails cleanly -- CheckpointWriteError naming the file and the cause, no temporary file left,
the previous checkpoint byte-identical -- and the train command reports it as an error (exit 2)
without a traceback. (SIGKILL at random moments and the refusal of a second run into the same
folder: tests/test_train_kill.py.)"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from stability_helpers import record

from reconstruct.train import checkpoint as ckpt
from reconstruct.train.checkpoint import (
    CheckpointWriteError,
    load_checkpoint,
    save_checkpoint,
)

ROOT = Path(__file__).resolve().parents[2]


def first_checkpoint(folder: Path) -> tuple[Path, bytes]:
    path = save_checkpoint({"step": 1, "weights": torch.arange(10.0)}, folder / "checkpoint.pt")
    return path, path.read_bytes()


def assert_previous_kept(path: Path, before: bytes) -> None:
    assert path.read_bytes() == before
    assert load_checkpoint(path)["step"] == 1
    assert [p.name for p in path.parent.iterdir()] == [path.name], "a temporary file was left"


def test_disk_full_in_the_middle_of_the_write(tmp_path, monkeypatch):
    path, before = first_checkpoint(tmp_path)
    real_open = open

    class HalfWritten:
        """A file that takes half of what is written, then reports ENOSPC (a full disk)."""

        def __init__(self, *a, **k):
            self.f = real_open(*a, **k)

        def write(self, data):
            self.f.write(bytes(data)[: len(data) // 2])
            self.f.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    monkeypatch.setattr(ckpt, "open", HalfWritten, raising=False)
    with pytest.raises(CheckpointWriteError, match="checkpoint.pt: checkpoint not written .No space left") as info:
        save_checkpoint({"step": 2, "weights": torch.zeros(10_000)}, path)
    assert info.value.errno == errno.ENOSPC and isinstance(info.value, OSError)
    monkeypatch.undo()
    assert_previous_kept(path, before)
    record("disk full (ENOSPC) mid-write", message=str(info.value))


def test_read_only_folder(tmp_path, monkeypatch):
    """The folder became read-only (the temporary file cannot be created). As root, chmod does not
    stop writes: the error is injected; test_real_read_only_mount uses a real one where it can."""
    path, before = first_checkpoint(tmp_path)

    def refuse(*a, **k):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr("tempfile.mkstemp", refuse)
    with pytest.raises(CheckpointWriteError, match="Read-only file system") as info:
        save_checkpoint({"step": 2}, path)
    assert info.value.errno == errno.EROFS
    monkeypatch.undo()
    assert_previous_kept(path, before)


def test_rename_fails(tmp_path, monkeypatch):
    path, before = first_checkpoint(tmp_path)

    def refuse(*a, **k):
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(CheckpointWriteError, match="Input/output error"):
        save_checkpoint({"step": 2}, path)
    monkeypatch.undo()
    assert_previous_kept(path, before)


def _run_python(code: str, **kw) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120, check=False, **kw)


SECOND_SAVE = """
import sys, torch
from reconstruct.train.checkpoint import save_checkpoint, CheckpointWriteError
try:
    save_checkpoint({"step": 2, "weights": torch.randn(200_000)}, sys.argv[1])
except CheckpointWriteError as exc:
    print("ERRNO", exc.errno, exc)
    sys.exit(0)
print("WRITTEN")
"""


def test_file_size_limit_real_failure(tmp_path):
    """A real failing write without root: RLIMIT_FSIZE makes write() fail with EFBIG part-way
    through the file, as a full disk does (torch.save straight into the file reported this as
    "[enforce fail at inline_container.cc:672] . unexpected pos 768 vs 662")."""
    path, before = first_checkpoint(tmp_path)
    code = "import resource, signal\nsignal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n" \
           "resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, resource.RLIM_INFINITY))\n" + SECOND_SAVE
    out = subprocess.run([sys.executable, "-c", code, str(path)], check=False, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert f"ERRNO {errno.EFBIG}" in out.stdout and "File too large" in out.stdout, out.stdout
    assert_previous_kept(path, before)
    record("file size limit (EFBIG, real)", message=out.stdout.strip())


def test_real_read_only_mount(tmp_path):
    """A real read-only file system: a tmpfs remounted read-only in a user namespace (no root
    needed, but the kernel must allow unprivileged user namespaces; skipped where it does not)."""
    unshare = shutil.which("unshare")
    if unshare is None:
        pytest.skip("no unshare(1)")
    folder = tmp_path / "ro"
    folder.mkdir()
    script = textwrap.dedent(f"""
        set -e
        mount -t tmpfs none {folder}
        {sys.executable} -c 'import torch; from reconstruct.train.checkpoint import save_checkpoint; save_checkpoint({{"step": 1}}, "{folder}/checkpoint.pt")'
        sha256sum {folder}/checkpoint.pt > {tmp_path}/before.sha
        mount -o remount,ro {folder}
        {sys.executable} -c '{SECOND_SAVE}' {folder}/checkpoint.pt
        sha256sum {folder}/checkpoint.pt > {tmp_path}/after.sha
        ls -A {folder}
    """)
    probe = subprocess.run([unshare, "-rm", "true"], capture_output=True, check=False)
    if probe.returncode != 0:
        pytest.skip(f"user namespaces unavailable: {probe.stderr.decode().strip()}")
    out = subprocess.run([unshare, "-rm", "sh", "-c", script], check=False, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert f"ERRNO {errno.EROFS}" in out.stdout, out.stdout
    assert (tmp_path / "before.sha").read_text() == (tmp_path / "after.sha").read_text()
    assert out.stdout.strip().splitlines()[-1] == "checkpoint.pt"  # no temporary file
    record("read-only mount (EROFS, real)", message=out.stdout.strip().splitlines()[0])


def test_train_command_reports_a_failed_checkpoint(tmp_path, monkeypatch, capsys):
    """The disk fills up at the third checkpoint of `train`: exit status 2 with the cause, no
    traceback; the second checkpoint is kept byte-identical; the run folder's lock is released and
    the run resumes from that checkpoint once the disk has room again."""
    from app.cli import main

    run = tmp_path / "run"
    scene = "synthetic:seed=1,frames=3,size=48,azimuths=8,eval_frames=1,texture_size=128"
    args = ["train", "--scene", scene, "--out", str(run), "--iters", "6", "--gaussian-res", "32", "--hidden", "16",
            "--quiet", "--eval-every", "1000", "--set", "checkpoint_every_seconds=0", "--set", "crop_margin=4",
            "--threads", "1"]
    real_save, calls, kept = ckpt.save_checkpoint, [], {}

    def filling_disk(state, path):
        calls.append(state["step"])
        if len(calls) >= 3:
            kept.setdefault("bytes", Path(path).read_bytes())
            raise CheckpointWriteError(errno.ENOSPC, f"{path}: checkpoint not written (No space left on device); "
                                       "the previous checkpoint, if any, is kept")
        return real_save(state, path)

    monkeypatch.setattr("reconstruct.train.trainer.save_checkpoint", filling_disk)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "error:" in err and "No space left on device" in err and "Traceback" not in err
    assert (run / "checkpoint.pt").read_bytes() == kept["bytes"]
    assert load_checkpoint(run / "checkpoint.pt")["step"] == calls[1]
    assert (run / ".lock").read_text() == ""  # released
    monkeypatch.undo()
    assert main(args) == 0
    assert load_checkpoint(run / "checkpoint.pt")["step"] == 6


def test_short_write_of_a_metrics_record_is_taken_back(tmp_path, monkeypatch):
    """A nearly full disk writes part of a line: the log must not keep it (it would join the next
    record and lose that one too)."""
    import os as _os

    from reconstruct.train.metrics_log import MetricsLog

    log = MetricsLog(tmp_path / "metrics.jsonl")
    log.append({"kind": "train", "step": 1})
    real = _os.write
    monkeypatch.setattr("reconstruct.train.metrics_log.os.write", lambda fd, b: real(fd, b[: len(b) // 2]))
    with pytest.raises(OSError, match="short write"):
        log.append({"kind": "train", "step": 2})
    monkeypatch.undo()
    log.append({"kind": "train", "step": 3})
    assert [r["step"] for r in log.read()] == [1, 3]
