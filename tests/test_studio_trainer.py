"""The studio's trainer thread without a window: Stage II start and settings applied between steps,
frozen copies for exports, novel poses in the live view, the published status."""

from __future__ import annotations

import time

import pytest
import torch


def _wait(cond, timeout=60.0, what=""):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if cond():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def trainer(tiny_scene, tiny_config):
    from app.studio.trainer_thread import TrainerThread
    from reconstruct.train.trainer import Trainer

    tiny_config.iters = 100000
    t = TrainerThread(Trainer(tiny_scene, tiny_config), publish_every=2)
    yield t
    t.stop(save=False)


SMALL_STAGE2 = {"num_azimuths": 8, "prior_size": 32, "iters": 100000}


def test_stage2_start_and_settings_between_steps(trainer):
    """The GUI's actions reach the trainer between steps: Stage II starts on the same avatar state
    with the panel's settings, ratio changes go into the running plan, a threshold change re-runs
    view selection, a bad combination is refused as a whole with a message."""
    t = trainer.trainer
    state = t.state
    assert trainer.status().stage == 1
    settings = {"canonical_ratio": 0.8, "given_view_ratio": 0.3, "visibility_threshold": 0.5, "lambda_sds": 0.2,
                "sds_t0": 50.0, "sds_k": 20.0, "progressive": True, "prior": "builtin", "prior_path": None,
                **SMALL_STAGE2}
    trainer.set_stage2_settings(settings)
    trainer.start()
    _wait(lambda: trainer.status().step >= 2, what="Stage I steps")
    trainer.start_stage2()
    _wait(lambda: trainer.status().stage == 2, what="Stage II")
    assert t.state is state  # the same avatar, a new plan
    cfg = t.plan.settings
    assert (cfg.canonical_ratio, cfg.given_view_ratio, cfg.lambda_sds, cfg.sds_t0, cfg.sds_k) == (0.8, 0.3, 0.2, 50.0, 20.0)
    _wait(lambda: trainer.status().stage_step >= 2 and trainer.history()[-1].stage == 2, what="Stage II steps")
    assert trainer.latest_snapshot().stage == 2
    assert trainer.status().candidate_views == len(t.plan.selected_views) == 9 * (1 + len(t.plan.reference_frames()))

    # a ratio change: into the running plan, no view re-selection
    spaces = t.plan.spaces
    trainer.set_stage2_settings({**settings, "canonical_ratio": 0.25})
    _wait(lambda: t.plan.settings.canonical_ratio == 0.25, what="ratio")
    assert t.plan.spaces is spaces
    # a threshold change re-runs view selection (on the trainer thread)
    trainer.set_stage2_settings({**settings, "canonical_ratio": 0.25, "visibility_threshold": 0.3})
    _wait(lambda: t.plan.spaces is not spaces, what="view selection")
    assert t.plan.settings.visibility_threshold == 0.3
    # a bad combination is refused as a whole, with a message; the running settings are unchanged
    trainer.set_stage2_settings({**settings, "given_view_ratio": 1.5, "canonical_ratio": 0.9})
    _wait(lambda: trainer.status().stage2_message is not None, what="refusal")
    assert "given_view_ratio" in trainer.status().stage2_message and t.plan.settings.canonical_ratio == 0.25
    # starting again says so
    trainer.start_stage2()
    _wait(lambda: trainer.status().stage2_message == "Stage II is already running", what="already running")
    assert trainer.status().error is None


def test_stage2_that_cannot_start_is_a_message(trainer):
    trainer.set_stage2_settings({"prior": "zero123", "prior_path": "/no/such/zero123", **SMALL_STAGE2})
    trainer.start()
    _wait(lambda: trainer.status().step >= 1, what="a step")
    trainer.start_stage2()
    _wait(lambda: trainer.status().stage2_message is not None, what="message")
    assert "could not start" in trainer.status().stage2_message and "/no/such/zero123" in trainer.status().stage2_message
    n = trainer.status().step
    _wait(lambda: trainer.status().step > n, what="Stage I going on")
    assert trainer.status().stage == 1 and trainer.status().error is None


def test_frozen_copy_between_steps_does_not_follow_training(trainer):
    from reconstruct.train.trainer import Trainer

    trainer.start()
    _wait(lambda: trainer.status().step >= 1, what="a step")
    frozen = trainer.call_between_steps(Trainer.frozen).result(timeout=60)
    model = frozen.state.model
    before = [p.detach().clone() for p in model.parameters()]
    step = trainer.status().step
    _wait(lambda: trainer.status().step >= step + 3, what="more steps")
    assert all(torch.equal(a, b) for a, b in zip(before, model.parameters()))
    live = dict(trainer.trainer.model.named_parameters())
    assert any(not torch.equal(p, live[k]) for k, p in model.named_parameters())
    assert frozen.body is trainer.trainer.state.body and frozen.step <= trainer.status().step
    trainer.stop(save=False)
    # after the loop ended, calls run at once on the caller's thread
    assert trainer.call_between_steps(lambda t: t.step_count).result(timeout=5) == trainer.trainer.step_count


def test_novel_pose_published_in_live_view(trainer):
    import numpy as np

    trainer.pause()
    trainer.start()
    _wait(lambda: len(trainer.latest_snapshot()) > 0, what="first snapshot")
    video = trainer.latest_snapshot()
    trainer.set_view(novel="arms_up", novel_index=trainer.novel_length - 1)
    _wait(lambda: trainer.latest_snapshot().version != video.version, what="novel snapshot")
    novel = trainer.latest_snapshot()
    # arms up: the highest Gaussians are now the hands, well above the head of the video pose
    assert novel.means[:, 2].max() > video.means[:, 2].max() + 0.1
    assert np.allclose(novel.scales, video.scales)


def test_motion_clip_is_a_pose_sequence_of_the_live_view(trainer, tmp_path):
    """A motion file retargeted onto the avatar is added as a named pose sequence: scrubbing it
    publishes its poses (the arms of the T-posed first frame are wider than the lowered middle);
    removing it falls back to the video's poses; built-in names and empty sequences are refused."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from motion_files import write_test_bvh

    from app.export import retarget_motion

    t = trainer.trainer
    m = retarget_motion(write_test_bvh(tmp_path / "arms.bvh", frames=40), t.state.body, t.scene)
    trainer.add_pose_sequence("motion:1", m.poses)
    n = len(m.poses)
    assert trainer.sequence_length("motion:1") == n and trainer.sequence_length("nothing") == 0
    with pytest.raises(ValueError, match="built-in"):
        trainer.add_pose_sequence("walk", m.poses)
    with pytest.raises(ValueError, match="no poses"):
        trainer.add_pose_sequence("motion:2", [])
    trainer.pause(True)
    trainer.start()
    widths = {}
    for k in (0, n // 2):
        trainer.set_view(novel="motion:1", novel_index=k)
        _wait(lambda k=k: trainer.published and trainer.published[0] == ("observation", 0, "motion:1", k),
              what=f"motion frame {k}")
        x = trainer.latest_snapshot().means[:, 0]
        widths[k] = float(x.max() - x.min())
    assert widths[0] > widths[n // 2] + 0.5, widths  # T-pose arms out, then down
    trainer.remove_pose_sequence("motion:1")
    _wait(lambda: trainer.published and trainer.published[0] == ("observation", 0, "", 0), what="video pose")
    assert trainer.status().error is None


def test_reopened_run_shows_its_logged_curves(tiny_scene, tiny_config, tmp_path):
    """The training panel's plots of a reopened run start from its metrics log, not empty."""
    from app.studio.trainer_thread import TrainerThread
    from reconstruct.train.trainer import Trainer

    s = Trainer(tiny_scene, tiny_config, tmp_path)
    for _ in range(4):
        s.advance(log_every=2)
    s.maybe_evaluate(force=True)
    rows = TrainerThread(s).history()
    assert [r.step for r in rows] == [1, 2, 4, 4]  # evaluation at the first step, losses every 2, evaluation
    assert rows[-1].seen_psnr == pytest.approx(s.latest["seen_psnr"]) and rows[1].loss > 0


def test_sds_curve_follows_the_stage2_schedule():
    """The Stage II panel's λ_SDS curve is Eq. 14 over schedule epochs of the configured length."""
    from app.studio.panels.stage2 import sds_curve

    settings = {"lambda_sds": 0.3, "sds_t0": 100.0, "sds_k": 100.0, "progressive": True}
    x, y = sds_curve(settings, 800, points=801)  # default epoch_steps 2: halved at 400 and 600
    assert y[399] == 0.3 and y[400] == 0.15 and y[600] == 0.075
    x, y = sds_curve({**settings, "progressive": False}, 800, points=801)
    assert set(y) == {0.3}
