"""benchmarks/synthetic_photo.py: ``train`` leaves the scene's normal maps out (as a prepared photo
has none) and puts them back afterwards; ``refill`` re-runs Stage I's finish on a checkpoint and
scores what ``eval`` scores for a run whose fill code has not changed."""

import json

import pytest

from app.cli import main as cli
from benchmarks.synthetic_photo import main, refill
from reconstruct.data.scene import Scene
from reconstruct.train import data as train_data
from tests.tiny_runs import tiny_train_args

PHOTO = "synthetic:seed=1,frames=1,size=48,azimuths=8,eval_frames=1,texture_size=128"


@pytest.fixture(scope="module")
def photo_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("synthetic_photo") / "run"
    seen = []
    original = train_data.TrainingData.__init__

    def spy(self, *args, **kwargs):
        original(self, *args, **kwargs)
        seen.append(self.use_normals)

    train_data.TrainingData.__init__ = spy
    try:
        assert main(tiny_train_args(run, 4, scene=PHOTO)) == 0
    finally:
        train_data.TrainingData.__init__ = original
    return run, seen


def test_train_leaves_the_normal_maps_out_and_puts_them_back(photo_run):
    run, seen = photo_run
    assert seen and not any(seen)
    from reconstruct.data.load import load_scene
    assert load_scene(PHOTO).has_normals  # the scene has them; the property is restored
    assert isinstance(Scene.__dict__["has_normals"], property)


def test_refill_scores_what_eval_scores(photo_run, capsys):
    run, _ = photo_run
    assert cli(["eval", str(run), "--json"]) == 0
    stored = json.loads(capsys.readouterr().out)
    r = refill(str(run))
    assert r["seen"] == pytest.approx(stored["seen_psnr"], abs=1e-4)
    assert r["unseen"] == pytest.approx(stored["unseen_psnr"], abs=1e-4)
    unseen_views = [v for v in stored["views"] if not v["seen"]]
    assert sorted(r["unseen_by_azimuth"]) == sorted({v["azimuth_deg"] for v in unseen_views})


def test_refill_runs_the_current_fill(photo_run, monkeypatch):
    # the fill is read at refill time: with the unseen colours painted white instead, unseen moves
    run, _ = photo_run
    import reconstruct.train.plan as plan

    base = refill(str(run))["unseen"]
    monkeypatch.setattr(plan, "fill_unseen_colors", lambda state, **kw: _paint_unseen_white(state))
    assert abs(refill(str(run))["unseen"] - base) > 0.5


def _paint_unseen_white(state):
    import torch

    model = state.model
    unseen = ~state.seen.cpu().bool()
    decoded = model.decode_raw(None, None)["color"].detach().cpu()
    with torch.no_grad():
        res = model.decoder.color_residual
        res.data[unseen] = ((8.0 - decoded[unseen]) / model.config.color_residual_gain).to(res.dtype)
    return int(unseen.sum())


def test_refill_takes_stage1_overrides(photo_run, monkeypatch, capsys):
    # the finish runs with the run's settings and the overrides: the fill is asked for the ring given
    run, _ = photo_run
    import reconstruct.train.plan as plan

    rings = []
    real = plan.fill_unseen_colors
    monkeypatch.setattr(plan, "fill_unseen_colors", lambda state, **kw: rings.append(kw["keep_ring"]) or real(state, **kw))
    refill(str(run))
    refill(str(run), ["fill_unseen_ring=8"])
    assert rings[1] == 8 and rings[0] != 8
    assert main(["refill", str(run), "--set", "fill_unseen_ring=8"]) == 0 and rings[2] == 8
    assert str(run) in capsys.readouterr().out
    assert main(["refill", str(run), "--set"]) == 2
