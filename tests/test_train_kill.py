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

ROOT = Path(__file__).resolve().parents[1]
SCENE = "synthetic:seed=1,frames=3,size=48,azimuths=8,eval_frames=1,texture_size=128"


def _train_cmd(run: Path, iters: int) -> list[str]:
    return [sys.executable, "-m", "app.cli", "train", "--scene", SCENE, "--out", str(run), "--iters", str(iters),
            "--gaussian-res", "32", "--hidden", "16", "--quiet", "--eval-every", "1",
            "--set", "checkpoint_every_seconds=0.3", "--set", "crop_margin=4", "--threads", "1"]


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
    assert not list(run.glob(".*.tmp")) and not list(run.glob("*.tmp"))
    lines = (run / "metrics.jsonl").read_text().splitlines()
    for line in lines[:-1]:
        json.loads(line)
    assert json.loads((run / "run.json").read_text())["scene"] == SCENE
    step = state["step"]

    # resume: same parameters as the checkpoint, then continue to a fixed step count
    from app.cli import main

    target = step + 3
    assert main(_train_cmd(run, target)[3:]) == 0
    final = load_checkpoint(ckpt)
    assert final["step"] == target
    records = [json.loads(l) for l in (run / "metrics.jsonl").read_text().splitlines()]
    assert all(r["step"] <= target for r in records)
    steps = [r["step"] for r in records if r["kind"] == "eval"]
    assert steps == sorted(steps)  # records after the checkpoint were dropped and redone


def test_resumed_parameters_equal_checkpoint(tiny_scene, tiny_config, tmp_path):
    from reconstruct.train.session import TrainingSession

    s = TrainingSession(tiny_scene, tiny_config, tmp_path)
    for _ in range(3):
        s.step()
    path = s.save()
    state = load_checkpoint(path)
    r = TrainingSession.resume(tiny_scene, tmp_path)
    for k, v in r.model.state_dict().items():
        assert torch.equal(v, state["model"][k])
    assert r.step_count == 3 and r.elapsed == pytest.approx(state["elapsed"])
