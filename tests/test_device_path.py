"""The whole path at toy size on each device there is: the CPU always, CUDA where present (these
are the GPU run's quick check, `benchmarks/gpu.py`'s tests section). Stage I with its finish,
Stage II with the built-in prior and a tiny random Zero123, a garment layer's Stage I and II,
evaluation, a .ply export and a snapshot: tensors of the CPU (seen flags, body model, fills) and
of the device must not mix anywhere on the way."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from tiny_runs import train_tiny

DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs CUDA")])]


def _until_done(trainer) -> set:
    kinds = set()
    while not trainer.done:
        out = trainer.step()
        assert not out.get("skipped"), out
        assert math.isfinite(out["loss"])
        kinds.add(out["step_kind"])
    return kinds


@pytest.mark.parametrize("device", DEVICES)
def test_cli_stages_eval_and_ply_on_the_device(device, tmp_path, capsys):
    from app.cli import main
    from reconstruct.ply import read_gaussians_ply

    run = train_tiny(tmp_path / "run", 4, "--device", device, "--stage", "all", "--stage2-iters", "4",
                     "--set2", "num_azimuths=12", "--set2", "prior_size=48")
    capsys.readouterr()
    assert main(["eval", str(run), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert math.isfinite(result["seen_psnr"]) and math.isfinite(result["unseen_psnr"])
    assert main(["export", str(run), "--ply", str(tmp_path / "a.ply"), "--frame", "1"]) == 0
    g = read_gaussians_ply(tmp_path / "a.ply")
    assert len(g.means) > 0 and np.isfinite(g.means).all()


@pytest.mark.parametrize("device", DEVICES)
def test_garment_layer_and_zero123_on_the_device(device, tiny_scene, tiny_config, tmp_path):
    pytest.importorskip("diffusers")
    from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, landmark_heights
    from reconstruct.priors.zero123_random import save_random_zero123
    from reconstruct.stage2.config import Stage2Config
    from reconstruct.stage2.plan import start_stage2
    from reconstruct.train.trainer import Trainer

    body = tiny_scene.body_model()
    m = landmark_heights(body)
    layer = build_garment_layer(body, VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05),
                                cols=16, row_step=0.06)
    cfg = dataclasses.replace(tiny_config, device=device, iters=6)
    t = Trainer(tiny_scene, cfg, tmp_path / "run", garment_layer=layer)
    (tmp_path / "run").mkdir()
    assert t.model.features.device.type == device and t.model.num_layer > 0
    assert _until_done(t) == {"given"}
    assert t.state.seen.any()
    start_stage2(t, Stage2Config(iters=4, num_azimuths=12, prior_size=48, given_view_ratio=0.0))
    assert _until_done(t) <= {"canonical", "observation"}
    folder = save_random_zero123(tmp_path / "zero123-tiny", "tiny", seed=0)
    t2 = Trainer(tiny_scene, dataclasses.replace(tiny_config, device=device, iters=4), tmp_path / "run2")
    (tmp_path / "run2").mkdir()
    _until_done(t2)
    plan = start_stage2(t2, Stage2Config(iters=4, num_azimuths=12, prior_size=48, given_view_ratio=0.0,
                                          prior="zero123", prior_path=str(folder)))
    assert plan.prior.c.device.type == device
    assert _until_done(t2) <= {"canonical", "observation"}
    rows, summary = t2.evaluate()
    assert math.isfinite(summary["unseen_psnr"])
    snap = t2.make_snapshot()
    assert isinstance(snap.means, np.ndarray) and len(snap.means) == t2.state.num_gaussians
    assert torch.device(device).type == t2.state.device.type
