"""Runs without ground truth for other views are first-class: held-out frames of the video are
validated (PSNR, SSIM, rendered-alpha IoU), a one-frame scene reports its training-view fit, and
no command fails because a kind of view is absent."""

from __future__ import annotations

import dataclasses
import json

import pytest

from reconstruct.train.validation import DEFAULT_HOLDOUT, holdout_frames, resolve_holdout
from tiny_runs import tiny_train_args


def test_holdout_frames():
    assert holdout_frames(20, 8) == [4, 12]
    assert holdout_frames(20, 0) == [] and holdout_frames(1, 8) == []
    assert holdout_frames(2, 1) == [0]  # never every frame
    assert holdout_frames(3, 2) == [1]
    with pytest.raises(ValueError, match="holdout"):
        holdout_frames(10, -1)


def _video_only(scene, frames=None):
    """The scene as one's own video would be: no evaluation views."""
    fr = scene.frames if frames is None else [scene.frames[i] for i in frames]
    return dataclasses.replace(scene, name=scene.name + "-video", eval_views=[], frames=fr)


def test_held_out_frames_are_not_trained_on_and_are_validated(tiny_scene, tiny_config):
    from reconstruct.train.trainer import Trainer

    scene = _video_only(tiny_scene)
    assert resolve_holdout(scene, None) == DEFAULT_HOLDOUT and resolve_holdout(tiny_scene, None) == 0
    tiny_config.holdout = 2
    t = Trainer(scene, tiny_config)
    assert t.val_frames == [1, 3] and t.data.frames == [0, 2] and t.val_kind == "held-out frames"
    used = {t.next_frame() for _ in range(20)}
    assert used == {0, 2}
    before = t.maybe_evaluate(force=True)
    for _ in range(30):
        t.step()
    after = t.maybe_evaluate(force=True)
    assert [r["frame"] for r in after["validation"]] == [1, 3] and after["views"] == []
    assert after["val_psnr"] > before["val_psnr"] and 0 < after["val_alpha_iou"] <= 1
    assert after["val_alpha_iou"] > before["val_alpha_iou"] - 0.05
    assert "seen_psnr" not in after


def test_one_frame_scene_reports_the_training_view_fit(tiny_scene, tiny_config):
    from reconstruct.train.trainer import Trainer

    t = Trainer(_video_only(tiny_scene, [0]), tiny_config)
    assert t.val_frames == [0] and t.data.frames == [0] and t.val_kind == "training-view fit"
    rec = t.maybe_evaluate(force=True)
    assert rec["val_kind"] == "training-view fit" and rec["val_psnr"] > 0


def test_train_eval_and_report_on_a_scene_without_evaluation_views(tiny_scene, tmp_path, capsys):
    from app.cli import main
    from reconstruct.data.scene_io import write_scene

    folder = tmp_path / "my_video"
    write_scene(_video_only(tiny_scene), folder)
    run = tmp_path / "run"
    args = tiny_train_args(run, 4, scene=str(folder))
    assert main(args + ["--stage", "all", "--stage2-iters", "2", "--set2", "num_azimuths=8",
                        "--set2", "prior_size=32"]) == 0
    out = capsys.readouterr()
    assert "no evaluation views" in out.err and "val PSNR" in out.out and "unseen PSNR" not in out.out
    assert (run / "error_vs_time.png").is_file()
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    evals = [r for r in records if r["kind"] == "eval"]
    assert {r["stage"] for r in evals} == {1, 2} and all(r["val_psnr"] > 0 for r in evals)
    assert main(["eval", str(run), "--json"]) == 0
