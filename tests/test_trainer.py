import json
import math
import os

import numpy as np
import pytest
import torch

from reconstruct.run_folder import RunFolder
from reconstruct.train.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from reconstruct.train.metrics_log import MetricsLog
from reconstruct.train.checkpoint import CHECKPOINT_NAME
from reconstruct.train.trainer import Trainer
from tiny_runs import TINY_SCENE, tiny_train_args


def test_training_reduces_the_loss_and_marks_visibility(tiny_scene, tiny_config):
    s = Trainer(tiny_scene, tiny_config)
    first = [s.step()["rgb"] for _ in range(4)]
    for _ in range(40):
        s.step()
    last = [s.step()["rgb"] for _ in range(4)]
    assert np.mean(last) < 0.7 * np.mean(first)
    snap = s.make_snapshot("canonical")
    n = s.state.num_gaussians
    assert snap.means.shape == (n, 3) and snap.visibility.shape == (n,) and snap.colors.shape == (n, 3)
    assert snap.step == s.step_count == 48
    # Eq. 7: front-facing Gaussians are first hits of the front camera, back-facing ones are not
    normals = s.state.model.base_normals.numpy()
    front = normals[:, 1] < -0.7
    back = normals[:, 1] > 0.7
    seen = snap.visibility.astype(bool)
    assert seen[front].mean() > 0.5
    assert seen[back].mean() < 0.1


def test_observation_snapshot_is_posed(tiny_scene, tiny_config):
    s = Trainer(tiny_scene, tiny_config)
    a = s.make_snapshot("observation", 0)
    c = s.make_snapshot("canonical")
    assert np.abs(a.means - c.means).max() > 0.01
    with pytest.raises(ValueError, match="space"):
        s.make_snapshot("world")


def test_checkpoint_resume_continues_identically(tiny_scene, tiny_config, tmp_path):
    torch.set_num_threads(1)
    straight = Trainer(tiny_scene, tiny_config, tmp_path / "a")
    (tmp_path / "a").mkdir()
    for _ in range(6):
        straight.step()
    straight.save()
    saved = {k: v.clone() for k, v in straight.state.model.state_dict().items()}
    after = [straight.step()["loss"] for _ in range(4)]

    resumed = RunFolder(tmp_path / "a").resume(tiny_scene)
    assert resumed.step_count == 6
    for k, v in resumed.state.model.state_dict().items():
        assert torch.equal(v, saved[k]), k
    again = [resumed.step()["loss"] for _ in range(4)]
    assert np.allclose(after, again, rtol=1e-5, atol=1e-7)


def test_checkpoint_write_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "ck.pt"
    save_checkpoint({"x": 1}, path)

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        save_checkpoint({"x": 2}, path)
    monkeypatch.undo()
    assert load_checkpoint(path)["x"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["ck.pt"]


def test_corrupt_and_foreign_checkpoints_are_named(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x00garbage")
    with pytest.raises(CheckpointError, match="bad.pt: not a readable checkpoint"):
        load_checkpoint(bad)
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a WonderHuman checkpoint"):
        load_checkpoint(tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="no checkpoint file"):
        load_checkpoint(tmp_path / "missing.pt")


def test_empty_mask_frame_is_an_error(tiny_scene, tiny_config):
    import copy

    scene = copy.deepcopy(tiny_scene)
    scene.frames[2].mask[:] = 0
    with pytest.raises(ValueError, match="frame 2 has an empty mask"):
        Trainer(scene, tiny_config)


def test_metrics_log_skips_a_torn_line(tmp_path):
    log = MetricsLog(tmp_path / "m.jsonl")
    log.append({"kind": "eval", "step": 1})
    log.append({"kind": "train", "step": 2})
    with open(tmp_path / "m.jsonl", "a") as f:
        f.write('{"kind": "ev')
    assert [r["step"] for r in log.read()] == [1, 2]
    log.truncate_after(1)
    assert [r["step"] for r in log.read()] == [1]


def test_evaluation_reports_seen_and_unseen(tiny_scene, tiny_config):
    s = Trainer(tiny_scene, tiny_config)
    rows, summary = s.evaluate()
    assert len(rows) == len(tiny_scene.eval_views)
    assert summary["seen_psnr"] is not None and summary["unseen_psnr"] is not None
    assert summary["seen_lpips"] is None  # no weights given


def test_a_run_trained_on_cuda_opens_where_there_is_none(tiny_scene, tiny_config, tmp_path, monkeypatch, capsys):
    """The device is where this process runs, not part of the run: a checkpoint whose settings name
    CUDA opens on the CPU on a machine without it (with a note), and resumes there as it would have;
    asking for CUDA explicitly there is an error. CUDA is made absent even where a GPU is."""
    import dataclasses

    from reconstruct.run_folder import placed_on

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    run = tmp_path / "run"
    run.mkdir()
    t = Trainer(tiny_scene, tiny_config, run)
    for _ in range(3):
        t.step()
    state = t.state_dict()
    state["config"] = {**state["config"], "device": "cuda"}  # as a GPU machine wrote it
    save_checkpoint(state, run / CHECKPOINT_NAME)
    capsys.readouterr()
    resumed = RunFolder(run).resume(tiny_scene)
    assert resumed.config.device == "cpu" and resumed.state.device == torch.device("cpu")
    assert "trained on CUDA; this machine has none, so it runs on the CPU" in capsys.readouterr().err
    assert resumed.step_count == 3 and math.isfinite(resumed.step()["loss"])
    with pytest.raises(RuntimeError, match="--device cuda: CUDA is not available"):
        RunFolder(run).resume(tiny_scene, device="cuda")
    cuda_cfg = dataclasses.replace(tiny_config, device="cuda")
    assert placed_on(cuda_cfg, "cpu", "x").device == "cpu" and placed_on(tiny_config, None, "x") is tiny_config


def test_cli_train_eval_and_bad_input(tmp_path, capsys):
    from app.cli import main

    scene = TINY_SCENE
    run = tmp_path / "run"
    assert main(["train", "--scene", scene, "--out", str(run), "--iters", "0"]) == 2
    assert "--iters must be at least 1" in capsys.readouterr().err
    assert main(["train", "--scene", "/no/such/scene", "--out", str(run), "--iters", "2"]) == 2
    assert "no such scene folder" in capsys.readouterr().err
    args = tiny_train_args(run)
    assert main(args) == 0
    assert (run / CHECKPOINT_NAME).is_file() and (run / "error_vs_time.png").is_file()
    capsys.readouterr()
    assert main(["eval", str(run), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["step"] == 3 and len(result["views"]) == 8
    # a corrupt checkpoint is reported and left in place
    (run / CHECKPOINT_NAME).write_bytes(b"junk")
    assert main(args) == 2
    assert "not a readable checkpoint" in capsys.readouterr().err
    assert (run / CHECKPOINT_NAME).read_bytes() == b"junk"
    assert main(["eval", str(tmp_path)]) == 2
    assert "not a training run" in capsys.readouterr().err


def test_second_trainer_on_a_run_folder_is_refused(tmp_path):
    from reconstruct.run_folder import RunLock, RunLockedError

    with RunLock(tmp_path):  # held: a second holder (another open file description) is refused
        assert (tmp_path / ".lock").read_text() == str(os.getpid())
        with pytest.raises(RunLockedError, match=f"another training process \\(pid {os.getpid()}\\)"):
            with RunLock(tmp_path):
                pass
    (tmp_path / ".lock").write_text("999999999")  # a lock file left by a dead process does not block
    with RunLock(tmp_path):
        pass
    assert (tmp_path / ".lock").read_text() == ""


def test_pose_refinement_moves_the_poses(tiny_scene, tiny_config):
    tiny_config.pose_refinement = True
    tiny_config.pose_refinement_start = 0.0
    s = Trainer(tiny_scene, tiny_config)
    for _ in range(4):
        s.step()
    assert s.state.pose_delta.detach().abs().max() > 0
    refined = s.state.refined_pose(0)
    assert refined.joint_rotations.shape == tiny_scene.frames[0].pose.joint_rotations.shape
    # the limbs move; fingers, toes and the eyes (a few pixels each) keep the fitted pose
    labels = s.state.body.bone_labels
    small = np.array([any(k in b for k in ("finger", "toe", "eye")) for b in labels])
    assert small.sum() > 20 and not s.state.refinable[:-2, 0].numpy()[small].any()
    moved = np.abs(refined.joint_rotations - tiny_scene.frames[0].pose.joint_rotations).max(1)
    assert moved[~small].max() > 0 and moved[small].max() == 0
    assert s.state.pose_delta.detach()[:, :-2][:, torch.from_numpy(small)].abs().max() == 0  # no gradient there
    # the refined transforms are the body model's for the refined pose
    T = s.state.body.bone_transforms(refined).float()
    assert torch.allclose(s.state.frame_transforms(0), T, atol=1e-5)


def test_snapshots_cross_threads(tiny_scene, tiny_config):
    import threading

    s = Trainer(tiny_scene, tiny_config)
    seen_versions = []

    def train():
        for _ in range(3):
            s.step()
            s.publish("canonical")

    t = threading.Thread(target=train)
    t.start()
    while t.is_alive():
        seen_versions.append(s.snapshots.latest().version)
    t.join()
    final = s.snapshots.latest()
    assert final.version == 3 and final.step == 3
    assert seen_versions == sorted(seen_versions)


def test_the_studio_opens_on_the_device_asked_for(tiny_scene, tiny_config, tmp_path, monkeypatch, capsys):
    """The studio's --device reaches its trainer (a new avatar and a resumed run), and a run
    trained on CUDA opens in the studio on a machine without it. CUDA is made absent."""
    import dataclasses

    from app.cli import build_parser
    from app.studio import window

    assert build_parser().parse_args(["--device", "cuda"]).studio_device == "cuda"
    assert build_parser().parse_args([]).studio_device is None
    monkeypatch.setattr("reconstruct.data.load.load_scene", lambda spec, progress=False: tiny_scene)  # no build
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    cuda_cfg = dataclasses.replace(tiny_config, device="cuda")
    trainer, run, lock = window._open_trainer("synthetic:seed=1", None, cuda_cfg, False, "cpu")
    assert trainer.config.device == "cpu" and run is None
    with pytest.raises(RuntimeError, match="--device cuda: CUDA is not available"):
        window._open_trainer("synthetic:seed=1", None, tiny_config, False, "cuda")
    folder = tmp_path / "run"
    folder.mkdir()
    t = Trainer(tiny_scene, tiny_config, folder)
    t.step()
    state = t.state_dict()
    state["config"] = {**state["config"], "device": "cuda"}
    save_checkpoint(state, folder / CHECKPOINT_NAME)
    (folder / "run.json").write_text(json.dumps({"scene": "synthetic:seed=1", "stage": 1}))
    trainer, run, lock = window._open_trainer("synthetic:seed=1", folder, None, False)
    try:
        assert trainer.config.device == "cpu" and trainer.step_count == 1
    finally:
        lock.release()


def test_prepared_videos_refine_their_poses_and_the_corrections_share_no_common_part(tiny_scene, tiny_config):
    """A scene ``prepare`` fitted to a video refines its poses without being asked; a synthetic
    scene (exact poses) and a photo (one frame) do not. The corrections of the frames trained so
    far have a zero mean (RowAdam's centring); the frames no step drew keep none."""
    import dataclasses

    from reconstruct.train.trainer import refines_poses

    video = dataclasses.replace(tiny_scene, meta={**tiny_scene.meta, "source": "video"})
    photo = dataclasses.replace(video, frames=video.frames[:1], meta={**video.meta, "source": "image"})
    assert refines_poses(video, tiny_config, 4)
    assert not refines_poses(video, tiny_config, 1)
    assert not refines_poses(photo, tiny_config, 1)
    assert not refines_poses(tiny_scene, tiny_config, 4)
    assert not refines_poses(video, dataclasses.replace(tiny_config, pose_refinement_prepared=False), 4)
    assert refines_poses(tiny_scene, dataclasses.replace(tiny_config, pose_refinement=True), 4)

    tiny_config.pose_refinement_start = 0.0
    s = Trainer(video, tiny_config)
    assert s.refines_poses and s.pose_optimizer is not None
    for _ in range(3):
        s.step()
    steps = s.pose_optimizer.state[s.state.pose_delta]["step"]
    drawn = steps > 0
    assert 1 < int(drawn.sum()) <= 3
    d = s.state.pose_delta.detach()
    assert float(d[drawn].abs().max()) > 0
    assert torch.allclose(d[drawn].mean(0), torch.zeros_like(d[0]), atol=1e-12)
    assert float(d[~drawn].abs().max()) == 0.0
    assert Trainer(tiny_scene, tiny_config).pose_optimizer is None
