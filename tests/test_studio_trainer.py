"""The studio's trainer thread without a window: Stage II start and settings applied between steps
(with a small stub Stage2Session, so the GUI logic is tested apart from Stage II itself), frozen
copies for exports, novel poses in the live view."""

from __future__ import annotations

import sys
import time
import types

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
def stub_stage2(monkeypatch):
    from reconstruct.train.session import TrainingSession

    class StubStage2(TrainingSession):
        stage = 2

        @classmethod
        def from_stage1(cls, session, config):
            new = cls.__new__(cls)
            new.__dict__.update(session.__dict__)
            new.stage2, new.stage2_step, new.reselected, new.from_session = config, 0, 0, session
            return new

        def step(self):
            out = super().step()
            self.stage2_step += 1
            return out

        def reselect_views(self):
            self.reselected += 1

        selected_views = []

    module = types.ModuleType("stub_stage2_session")
    module.Stage2Session = StubStage2
    monkeypatch.setitem(sys.modules, "stub_stage2_session", module)
    monkeypatch.setattr("app.studio.trainer_thread.STAGE2_MODULE", "stub_stage2_session")
    return StubStage2


@pytest.fixture
def trainer(tiny_scene, tiny_config):
    from app.studio.trainer_thread import TrainerThread
    from reconstruct.train.session import TrainingSession

    tiny_config.iters = 100000
    t = TrainerThread(TrainingSession(tiny_scene, tiny_config), publish_every=2)
    yield t
    t.stop(save=False)


def test_stage2_start_and_settings_between_steps(trainer, stub_stage2):

    s1 = trainer.session
    assert s1.stage == 1
    settings = {"canonical_ratio": 0.8, "given_view_ratio": 0.3, "visibility_threshold": 0.5, "lambda_sds": 0.2,
                "sds_t0": 50.0, "sds_k": 20.0, "progressive": True, "prior": "builtin", "prior_path": None}
    trainer.controls.update(stage2=dict(settings), stage2_version=1)
    trainer.start()
    _wait(lambda: s1.step_count >= 2, what="Stage I steps")
    trainer.controls.update(start_stage2=True)
    _wait(lambda: trainer.session.stage == 2, what="Stage II")
    s2 = trainer.session
    assert s2.from_session is s1 and s2.model is s1.model
    cfg = s2.stage2
    assert (cfg.canonical_ratio, cfg.given_view_ratio, cfg.lambda_sds, cfg.sds_t0, cfg.sds_k) == (0.8, 0.3, 0.2, 50.0, 20.0)
    _wait(lambda: s2.stage2_step >= 2 and trainer.history()[-1].stage == 2, what="Stage II steps")
    assert s2.snapshots.latest().step >= s1.step_count  # the new session publishes

    # a ratio change: copied into the same config object, no view re-selection
    trainer.controls.update(stage2={**settings, "canonical_ratio": 0.25}, stage2_version=2)
    _wait(lambda: cfg.canonical_ratio == 0.25, what="ratio")
    assert s2.stage2 is cfg and s2.reselected == 0
    # a threshold change re-runs view selection (on the trainer thread)
    trainer.controls.update(stage2={**settings, "canonical_ratio": 0.25, "visibility_threshold": 0.3},
                            stage2_version=3)
    _wait(lambda: s2.reselected == 1, what="reselect_views")
    assert cfg.visibility_threshold == 0.3
    # a bad combination is refused as a whole, with a message; the running config is unchanged
    trainer.controls.update(stage2={**settings, "given_view_ratio": 1.5, "canonical_ratio": 0.9}, stage2_version=4)
    _wait(lambda: trainer.stage2_message is not None, what="refusal")
    assert "given_view_ratio" in trainer.stage2_message and cfg.canonical_ratio == 0.25
    # starting again says so
    trainer.controls.update(start_stage2=True)
    _wait(lambda: trainer.stage2_message == "Stage II is already running", what="already running")
    assert trainer.error is None


def test_stage2_missing_module_is_a_message(trainer, monkeypatch):
    monkeypatch.setattr("app.studio.trainer_thread.STAGE2_MODULE", "reconstruct.stage2.no_such_module")
    trainer.controls.update(start_stage2=True)
    trainer.start()
    _wait(lambda: trainer.stage2_message is not None, what="message")
    assert "not available" in trainer.stage2_message
    s = trainer.session
    n = s.step_count
    _wait(lambda: s.step_count > n, what="Stage I going on")
    assert trainer.session.stage == 1 and trainer.error is None


def test_frozen_copy_between_steps_does_not_follow_training(trainer):
    from app.export import frozen_copy

    trainer.start()
    _wait(lambda: trainer.session.step_count >= 1, what="a step")
    frozen = trainer.call_between_steps(frozen_copy).result(timeout=60)
    before = [p.detach().clone() for p in frozen.model.parameters()]
    step = trainer.session.step_count
    _wait(lambda: trainer.session.step_count >= step + 3, what="more steps")
    assert all(torch.equal(a, b) for a, b in zip(before, frozen.model.parameters()))
    live = dict(trainer.session.model.named_parameters())
    assert any(not torch.equal(p, live[k]) for k, p in frozen.model.named_parameters())
    assert frozen.run_dir is None and frozen.body is trainer.session.body
    trainer.stop(save=False)
    # after the loop ended, calls run at once on the caller's thread
    assert trainer.call_between_steps(lambda s: s.step_count).result(timeout=5) == trainer.session.step_count


def test_novel_pose_published_in_live_view(trainer):
    import numpy as np

    trainer.controls.update(paused=True)
    trainer.start()
    _wait(lambda: len(trainer.session.snapshots.latest()) > 0, what="first snapshot")
    video = trainer.session.snapshots.latest()
    trainer.controls.update(novel="arms_up", novel_index=trainer.novel_length - 1)
    _wait(lambda: trainer.session.snapshots.latest().version != video.version, what="novel snapshot")
    novel = trainer.session.snapshots.latest()
    # arms up: the highest Gaussians are now the hands, well above the head of the video pose
    assert novel.means[:, 2].max() > video.means[:, 2].max() + 0.1
    assert np.allclose(novel.scales, video.scales)


def test_reopened_run_shows_its_logged_curves(tiny_scene, tiny_config, tmp_path):
    """The training panel's plots of a reopened run start from its metrics log, not empty."""
    from app.studio.trainer_thread import TrainerThread
    from reconstruct.train.session import TrainingSession

    s = TrainingSession(tiny_scene, tiny_config, tmp_path)
    for _ in range(4):
        s.advance(log_every=2)
    s.maybe_evaluate(force=True)
    rows = TrainerThread(s).history()
    assert [r.step for r in rows] == [1, 2, 4, 4]  # evaluation at the first step, losses every 2, evaluation
    assert rows[-1].seen_psnr == pytest.approx(s.latest["seen_psnr"]) and rows[1].loss > 0


def test_sds_curve_follows_the_stage2_schedule():
    """The Stage II panel's λ_SDS curve is Eq. 14 over schedule epochs of the configured length."""
    from app.studio.panels import sds_curve

    settings = {"lambda_sds": 0.3, "sds_t0": 100.0, "sds_k": 100.0, "progressive": True}
    x, y = sds_curve(settings, 800, points=801)  # default epoch_steps 2: halved at 400 and 600
    assert y[399] == 0.3 and y[400] == 0.15 and y[600] == 0.075
    x, y = sds_curve({**settings, "progressive": False}, 800, points=801)
    assert set(y) == {0.3}
