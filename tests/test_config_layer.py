"""One config layer: overrides converted by each field's type annotation, one parser for --set and
--set2, errors that name the setting and its type."""

from __future__ import annotations

import pytest

from reconstruct import config as C
from reconstruct.stage2.config import Stage2Config
from reconstruct.train.config import Stage1Config
from tiny_runs import tiny_train_args


def test_values_convert_by_annotation_not_by_default():
    o = C.parse_overrides(Stage1Config, ["threads=4", "lpips_backbone=/w/alex.pth", "minutes=2.5",
                                         "pose_refinement=yes", "lr_milestones=0.5,0.9", "background=[1, 1, 1]",
                                         "avatar.hidden=64"], "Stage I")
    assert o == {"threads": 4, "lpips_backbone": "/w/alex.pth", "minutes": 2.5, "pose_refinement": True,
                 "lr_milestones": (0.5, 0.9), "background": (1.0, 1.0, 1.0), "avatar": {"hidden": 64}}
    assert isinstance(o["threads"], int)
    cfg = C.with_overrides(Stage1Config(), o)
    assert cfg.avatar.hidden == 64 and cfg.avatar.feature_channels == 64 and cfg.threads == 4
    assert C.parse_overrides(Stage1Config, ["threads=none"], "Stage I") == {"threads": None}
    assert C.parse_overrides(Stage2Config, ["minutes=0.2", "prior_path=none"], "Stage II") == \
        {"minutes": 0.2, "prior_path": None}


@pytest.mark.parametrize("item, message", [
    ("iters=abc", r"--set iters \(Stage I setting of type int\): expected int, found 'abc'"),
    ("iters=2.5", r"iters .*expected int"),
    ("pose_refinement=maybe", r"pose_refinement .*expected bool"),
    ("background=1,1", r"background .*expected 3 values"),
    ("no_such=1", r"unknown Stage I setting 'no_such'"),
    ("avatar.no_such=1", r"unknown Stage I setting 'avatar.no_such'"),
    ("avatar=3", r"unknown Stage I setting 'avatar'"),
    ("iters", r"KEY=VALUE"),
])
def test_bad_overrides_name_the_setting_and_type(item, message):
    with pytest.raises(ValueError, match=message):
        C.parse_overrides(Stage1Config, [item], "Stage I")


def test_from_dict_converts_json_and_refuses_unknown_keys():
    d = Stage2Config(lr_milestones=(0.5,)).to_dict()
    d["lr_milestones"] = [0.5]  # JSON has lists
    assert Stage2Config.from_dict(d).lr_milestones == (0.5,)
    with pytest.raises(ValueError, match=r"unknown .*settings \['bogus'\]"):
        Stage2Config.from_dict({**d, "bogus": 1})
    cfg = Stage1Config.from_dict(Stage1Config().to_dict())
    assert cfg == Stage1Config()


def test_cli_set_and_set2(tmp_path, capsys):
    from app.cli import main

    run = tmp_path / "run"
    base = tiny_train_args(run, 2)
    # the LPIPS file error, not a conversion error; threads an int
    assert main(base + ["--set", "threads=1", "--set", "lpips_backbone=/nonexistent.pth"]) == 2
    err = capsys.readouterr().err
    assert "/nonexistent.pth" in err and "expected" not in err and "could not convert" not in err
    assert main(base + ["--set", "iters=abc"]) == 2
    assert "--set iters (Stage I setting of type int): expected int, found 'abc'" in capsys.readouterr().err
    assert main(base + ["--set2", "minuts=0.2"]) == 2
    assert "unknown Stage II setting 'minuts'" in capsys.readouterr().err
    # --set2 minutes=0.2 works: Stage II ends by its minutes
    assert main(base + ["--stage", "all", "--set", "threads=1", "--set2", "minutes=0.2", "--set2", "iters=3",
                        "--set2", "num_azimuths=8", "--set2", "prior_size=32"]) == 0
    from reconstruct.train.checkpoint import load_checkpoint

    state = load_checkpoint(run / "checkpoint.pt")
    assert state["stage"] == 2 and state["plan"]["settings"]["minutes"] == 0.2 and state["config"]["threads"] == 1
