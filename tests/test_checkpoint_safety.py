"""Run folders are data: a checkpoint whose pickle would run code is refused by every command that
opens a run (eval, export, train resuming, the studio's --run goes through the same reader), with a
clear error naming the file; truncated and random-byte checkpoints likewise; nothing else in the
folder is touched. Checkpoints of the earlier format are converted once by ``migrate``."""

from __future__ import annotations

import io
import os
import pickle

import pytest
import torch

from reconstruct.run_folder import RunFolder
from reconstruct.train.checkpoint import CheckpointError, load_checkpoint, save_checkpoint, upgrade_v1
from tiny_runs import TINY_SCENE, train_tiny


class _Marker:
    """Unpickling this creates the marker file: what a hostile checkpoint would do."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("runs") / "run"
    return train_tiny(run)


def _listing(folder):
    """Every file's size and mtime (the lock file aside: taking the lock writes the holder's pid)."""
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.iterdir() if p.name != ".lock"}


def _hostile(path, marker):
    buf = io.BytesIO()
    good = load_checkpoint(path)
    torch.save({**good, "latest": {"note": _Marker(marker)}}, buf)
    return buf.getvalue()


def _commands(run, tmp_path):
    return [["eval", str(run), "--json"],
            ["export", str(run), "--orbit", "2", "--size", "32", "--out", str(tmp_path / "o.gif"), "--quiet"],
            ["train", "--scene", TINY_SCENE, "--out", str(run), "--iters", "5", "--quiet"]]


@pytest.mark.parametrize("kind", ["hostile", "truncated", "random"])
def test_bad_checkpoints_are_refused_by_every_command(kind, trained_run, tmp_path, capsys):
    import shutil

    from app.cli import main

    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    marker = tmp_path / "MARKER"
    ckpt = run / "checkpoint.pt"
    data = {"hostile": lambda: _hostile(ckpt, marker), "truncated": lambda: ckpt.read_bytes()[:2000],
            "random": lambda: os.urandom(4096)}[kind]()
    ckpt.write_bytes(data)
    before = _listing(run)
    for argv in _commands(run, tmp_path):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert str(ckpt) in err and "Traceback" not in err, err
        if kind == "hostile":
            assert "refused" in err and "could run code" in err and "the global io.open" in err, err
        else:
            assert "not a readable checkpoint" in err, err
        assert not marker.exists()
        assert _listing(run) == before and ckpt.read_bytes() == data
    assert not (tmp_path / "o.gif").exists()
    with pytest.raises(CheckpointError):
        RunFolder(run).resume()
    assert not marker.exists()


def _v1_state(state: dict, extra_latest=None) -> dict:
    """The layout the earlier version wrote (TrainingSession.state()) for a Stage I run."""
    a = state["avatar"]
    return {"format": "wonderhuman-checkpoint", "version": 1, "stage": 1, "step": state["step"],
            "elapsed": state["elapsed"], "config": state["config"], "scene_spec": state["scene_spec"],
            "scene_name": state["scene_name"], "model": a["model"], "optimizer": state["optimizer"],
            "pose_delta": a["pose_delta"], "pose_optimizer": state["pose_optimizer"], "seen": a["seen"],
            "epoch_order": state["epoch_order"], "rng": state["rng"], "latest": {**state["latest"], **(extra_latest or {})},
            "nonfinite_skipped": 0, "restored_states": 0}


@pytest.mark.parametrize("needs_trust", [False, True])
def test_earlier_checkpoints_are_migrated_once(needs_trust, trained_run, tmp_path, capsys):
    import shutil

    import numpy as np

    from app.cli import main

    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    ckpt = run / "checkpoint.pt"
    current = load_checkpoint(ckpt)
    # an earlier run whose metrics held a numpy number: reading it needs full unpickling
    old = _v1_state(current, {"psnr": np.float64(20.5)} if needs_trust else None)
    buf = io.BytesIO()
    torch.save(old, buf)
    ckpt.write_bytes(buf.getvalue())
    assert main(["eval", str(run)]) == 2
    assert "earlier version" in capsys.readouterr().err or needs_trust
    if needs_trust:
        assert main(["migrate", str(run)]) == 2
        assert "--trust" in capsys.readouterr().err
        assert main(["migrate", str(run), "--trust"]) == 0
    else:
        assert main(["migrate", str(run)]) == 0
    assert "converted" in capsys.readouterr().out
    new = load_checkpoint(ckpt)
    assert new["version"] == 2 and new["step"] == current["step"]
    for k, v in current["avatar"]["model"].items():
        assert torch.equal(new["avatar"]["model"][k], v), k
    assert main(["migrate", str(run)]) == 0 and "already" in capsys.readouterr().out
    # the migrated run resumes and continues exactly as the current one does
    a, b = RunFolder(trained_run).resume(), RunFolder(run).resume()
    assert a.step() ["loss"] == pytest.approx(b.step()["loss"], rel=1e-6)


def test_upgrade_keeps_a_stage2_layout(tmp_path):
    old = {"stage": 2, "step": 10, "elapsed": 5.0, "config": {}, "model": {}, "optimizer": {}, "pose_delta": None,
           "seen": None, "rng": {"numpy": {}, "torch": None, "python": None},
           "stage2": {"config": {"iters": 4}, "step": 3, "elapsed": 1.0, "stage1_step": 7,
                      "kind_counts": {"given": 2, "canonical": 1}, "pseudo_colors": None, "trusted_seen": "T",
                      "canonical_reference": None, "spaces": [], "sds_note": None}}
    new = upgrade_v1(old)
    assert new["stage_step"] == 3 and new["stage_starts"] == {"1": 0, "2": 7} and new["avatar"]["trusted_seen"] == "T"
    assert new["plan"]["settings"] == {"iters": 4}


def test_plain_data_round_trips_through_the_data_only_reader(tmp_path):
    import random

    import numpy as np

    state = {"rng": {"numpy": np.random.default_rng(3).bit_generator.state, "torch": torch.get_rng_state(),
                     "python": random.getstate()}, "t": torch.arange(3), "nested": [1, (2.5, "x"), {"a": None}]}
    path = save_checkpoint(state, tmp_path / "c.pt")
    back = load_checkpoint(path)
    assert back["rng"]["numpy"] == state["rng"]["numpy"] and torch.equal(back["t"], state["t"])
    assert pickle.dumps(back["nested"]) == pickle.dumps(state["nested"])
