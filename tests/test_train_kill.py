"""A training run killed with SIGKILL at any moment resumes from its last checkpoint, and no file
of the run folder is ever left half-written."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from reconstruct.train.checkpoint import load_checkpoint
from tiny_runs import TINY_SCENE, tiny_train_args

ROOT = Path(__file__).resolve().parents[1]


def _train_cmd(run: Path, iters: int, *extra: str) -> list[str]:
    return [sys.executable, "-m", "app.cli", *tiny_train_args(run, iters, "--eval-every", "1", "--set",
                                                              "checkpoint_every_seconds=0.3", "--threads", "1", *extra)]


@pytest.mark.slow
def test_sigkill_then_resume(tmp_path, monkeypatch):
    monkeypatch.setenv("WONDERHUMAN_CACHE_DIR", os.environ.get("WONDERHUMAN_CACHE_DIR", str(Path.home() / ".cache" / "wonderhuman")))
    run = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(_train_cmd(run, 100000), cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    ckpt = run / "checkpoint.pt"
    deadline = time.time() + 240
    while time.time() < deadline and not (ckpt.exists() and load_checkpoint(ckpt)["step"] >= 5):
        time.sleep(0.2)
    assert ckpt.exists(), proc.stderr.read().decode()[-2000:] if proc.poll() is not None else "no checkpoint in time"
    time.sleep(0.37)  # kill at an arbitrary moment
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # nothing half-written: the checkpoint loads, every metrics line but a possibly torn last one parses
    state = load_checkpoint(ckpt)
    # at most the temporary file of a checkpoint write cut short (".checkpoint.XXXXXXXX.pt"; the next
    # write removes it -- checked after the resume below)
    assert len(list(run.glob(".checkpoint.*.pt"))) <= 1 and not list(run.glob("*.tmp"))
    lines = (run / "metrics.jsonl").read_text().splitlines()
    for line in lines[:-1]:
        json.loads(line)
    from reconstruct.data.load import canonical_scene_spec

    assert json.loads((run / "run.json").read_text())["scene"] == canonical_scene_spec(TINY_SCENE)
    step = state["step"]

    # resume: same parameters as the checkpoint, then continue to a fixed step count
    from app.cli import main

    target = step + 3
    assert main(_train_cmd(run, target)[3:]) == 0
    final = load_checkpoint(ckpt)
    assert final["step"] == target
    assert not list(run.glob(".checkpoint.*.pt"))
    records = [json.loads(l) for l in (run / "metrics.jsonl").read_text().splitlines()]
    assert all(r["step"] <= target for r in records)
    steps = [r["step"] for r in records if r["kind"] == "eval"]
    assert steps == sorted(steps)  # records after the checkpoint were dropped and redone


def test_resumed_parameters_equal_checkpoint(tiny_scene, tiny_config, tmp_path):
    from reconstruct.run_folder import RunFolder
    from reconstruct.train.trainer import Trainer

    s = Trainer(tiny_scene, tiny_config, tmp_path)
    for _ in range(3):
        s.step()
    path = s.save()
    state = load_checkpoint(path)
    r = RunFolder(tmp_path).resume(tiny_scene)
    for k, v in r.model.state_dict().items():
        assert torch.equal(v, state["avatar"]["model"][k])
    assert r.step_count == 3 and r.elapsed == pytest.approx(state["elapsed"])


def _wait_for_step(proc, ckpt: Path, step: int, timeout: float = 240) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline and not (ckpt.exists() and load_checkpoint(ckpt)["step"] >= step):
        if proc.poll() is not None:
            raise AssertionError(f"training exited early: {proc.stderr.read().decode()[-2000:]}")
        time.sleep(0.05)
    assert ckpt.exists() and load_checkpoint(ckpt)["step"] >= step, "no checkpoint in time"


@pytest.mark.slow
def test_sigkill_at_random_moments_loses_nothing(tmp_path, capsys):
    """Three SIGKILLs at random moments (seeded), each followed by a resume; while a run is alive
    a second one into the same folder is refused. Nothing is lost: every checkpoint loads, the
    step never goes back, and the final parameters equal those of a run never interrupted."""
    import random

    from app.cli import main

    rng = random.Random(20240611)
    run, straight = tmp_path / "run", tmp_path / "straight"
    # the learning rate must not depend on --iters (it differs between the killed runs and the last
    # one): no step decay within the run
    constant_lr = ("--set", "lr_milestones=2")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    ckpt = run / "checkpoint.pt"
    last_step = 0
    for kill in range(3):
        proc = subprocess.Popen(_train_cmd(run, 100000, *constant_lr), cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE)
        try:
            _wait_for_step(proc, ckpt, last_step + 2)
            if kill == 0:  # a second run into the folder of a live one is refused
                assert main(_train_cmd(run, 100000, *constant_lr)[3:]) == 2
                assert "another training process" in capsys.readouterr().err
            time.sleep(rng.uniform(0.0, 0.6))  # a random moment: mid-step, mid-checkpoint, mid-log
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        state = load_checkpoint(ckpt)
        assert state["step"] >= last_step, "a checkpoint went back in time"
        last_step = state["step"]
        # a kill mid-checkpoint may leave one temporary file; the next checkpoint write removes it
        assert len([p for p in run.iterdir() if p.name.startswith(".checkpoint.")]) <= 1
        for line in (run / "metrics.jsonl").read_text().splitlines()[:-1]:
            json.loads(line)
    # finish, and compare with an uninterrupted run of the same length (bit-identical: seeded,
    # one thread, deterministic kernels, optimiser and RNG states in the checkpoint)
    # (both in fresh processes like the killed ones: buffers computed at start-up, e.g. the LBS
    # inverses, can differ in the last bit with the state of a longer-lived process)
    target = last_step + 3
    for folder in (run, straight):
        done = subprocess.run(_train_cmd(folder, target, *constant_lr), check=False, cwd=ROOT, env=env, capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
    assert sorted(p.name for p in run.iterdir() if p.name.startswith(".") and p.name != ".lock") == []  # no stale temporaries (.lock: the run lock, kept)
    resumed, uninterrupted = load_checkpoint(ckpt), load_checkpoint(straight / "checkpoint.pt")
    assert resumed["step"] == uninterrupted["step"] == target
    for k, v in uninterrupted["avatar"]["model"].items():
        assert torch.equal(resumed["avatar"]["model"][k], v), k
