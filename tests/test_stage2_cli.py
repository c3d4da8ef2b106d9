"""``train --stage 2 / all`` end to end on a tiny scene, and its errors."""

from __future__ import annotations

import json

import pytest

SCENE = "synthetic:seed=1,frames=4,size=64,azimuths=8,eval_frames=1,texture_size=128"
TINY = ["--gaussian-res", "48", "--hidden", "32", "--set", "crop_margin=4",
        "--set2", "num_azimuths=12", "--set2", "prior_size=48", "--quiet"]


def _main(argv):
    from app.cli import main

    return main(argv)


@pytest.fixture(autouse=True)
def _small_features(monkeypatch):
    """Keep the avatar tiny: the CLI builds AvatarConfig() with paper channel counts."""
    from reconstruct.avatar import config as avatar_config

    orig = avatar_config.AvatarConfig.__init__.__defaults__
    fields = avatar_config.AvatarConfig.__dataclass_fields__
    monkeypatch.setattr(fields["feature_channels"], "default", 8)
    monkeypatch.setattr(fields["pose_feature_channels"], "default", 8)
    monkeypatch.setattr(fields["feature_resolution"], "default", 32)
    d = list(orig)
    names = list(fields)
    d[names.index("feature_channels")] = 8
    d[names.index("pose_feature_channels")] = 8
    d[names.index("feature_resolution")] = 32
    monkeypatch.setattr(avatar_config.AvatarConfig.__init__, "__defaults__", tuple(d))


def test_stage_all_then_resume_stage2(tmp_path, capsys):
    run = tmp_path / "run"
    assert _main(["train", "--scene", SCENE, "--out", str(run), "--stage", "all", "--iters", "6",
                  "--stage2-iters", "6"] + TINY) == 0
    records = [json.loads(l) for l in (run / "metrics.jsonl").read_text().splitlines()]
    evals = [r for r in records if r["kind"] == "eval"]
    assert {r["stage"] for r in evals} == {1, 2}  # the error-vs-time log spans both stages
    assert json.loads((run / "run.json").read_text())["stage"] == 2
    assert (run / "checkpoint_stage1.pt").exists()
    # more Stage II steps on the same run: resumes Stage II where it stopped
    assert _main(["train", "--out", str(run), "--stage", "2", "--stage2-iters", "9"] + TINY) == 0
    assert "resuming Stage II" in capsys.readouterr().err
    from reconstruct.train.checkpoint import load_checkpoint

    state = load_checkpoint(run / "checkpoint.pt")
    assert state["stage"] == 2 and state["stage_step"] == 9 and state["step"] == 15


def test_stage2_errors(tmp_path, capsys):
    assert _main(["train", "--out", str(tmp_path / "nothing"), "--stage", "2"] + TINY) != 0
    assert "train Stage I first" in capsys.readouterr().err
    run = tmp_path / "run"
    assert _main(["train", "--scene", SCENE, "--out", str(run), "--iters", "3"] + TINY) == 0
    assert _main(["train", "--out", str(run), "--stage", "2", "--visibility-threshold", "1.5"] + TINY) != 0
    assert "threshold must be in (0, 1)" in capsys.readouterr().err
    assert _main(["train", "--out", str(run), "--stage", "2", "--prior", "zero123",
                  "--prior-path", str(tmp_path / "missing")] + TINY) != 0
    err = capsys.readouterr().err
    assert "missing" in err
