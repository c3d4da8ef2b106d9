"""The normal prior of frames without a normal map (a user's photo or video): mean (1 - cos) between
each decoded Gaussian's normal and its texel's, in place of the normal loss."""

import dataclasses

import numpy as np
import torch

from reconstruct.data.scene import Scene
from reconstruct.train import losses as L
from reconstruct.train.config import Stage1Config
from reconstruct.train.trainer import Trainer


def test_normal_deviation_is_one_minus_the_cosine_of_the_angle_in_float64():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(200, 3))
    b = rng.normal(size=(200, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    angle = np.arccos(np.clip((a * b).sum(1), -1, 1))  # independent: through the angle
    want = float(np.mean(1.0 - np.cos(angle)))
    got = float(L.normal_deviation(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32)))
    assert abs(got - want) < 1e-6
    z = torch.tensor([[0.0, 0.0, 1.0]])
    assert float(L.normal_deviation(z, z)) == 0.0
    assert abs(float(L.normal_deviation(torch.tensor([[1.0, 0.0, 0.0]]), z)) - 1.0) < 1e-7
    assert abs(float(L.normal_deviation(-z, z)) - 2.0) < 1e-7


def _without_normals(scene: Scene) -> Scene:
    return dataclasses.replace(scene, frames=[dataclasses.replace(f, normal=None) for f in scene.frames])


def _deviation(trainer: Trainer) -> float:
    with torch.no_grad():
        model = trainer.state.model
        return float(L.normal_deviation(model.canonical(None).normals, model.base_normals))


def test_the_prior_stands_in_for_the_normal_loss_only_without_normal_maps(tiny_scene, tiny_config):
    assert tiny_scene.has_normals and tiny_config.lambda_normal_prior > 0
    with_maps = Trainer(tiny_scene, tiny_config).step()
    assert "normal" in with_maps and "normal_prior" not in with_maps
    plain = _without_normals(tiny_scene)
    without = Trainer(plain, tiny_config).step()
    assert "normal" not in without and without["normal_prior"] > -1e-6
    off = Trainer(plain, dataclasses.replace(tiny_config, lambda_normal_prior=0.0)).step()
    assert "normal" not in off and "normal_prior" not in off


def test_the_prior_keeps_the_normals_near_the_body_where_no_map_holds_them(tiny_scene, tiny_config):
    plain = _without_normals(tiny_scene)
    devs = {}
    for lam in (0.0, 1.0):
        t = Trainer(plain, dataclasses.replace(tiny_config, lambda_normal_prior=lam, lr_decoder=0.02))
        for _ in range(25):
            t.step()
        devs[lam] = _deviation(t)
    assert devs[0.0] > 0.005  # the image terms alone turn the discs
    assert devs[1.0] < 0.5 * devs[0.0]


def test_old_records_and_the_paper_settings_have_no_prior():
    rec = Stage1Config().to_dict()
    del rec["lambda_normal_prior"]
    assert Stage1Config.from_dict(rec).lambda_normal_prior == 0.0
    assert Stage1Config.paper().lambda_normal_prior == 0.0
    try:
        Stage1Config(lambda_normal_prior=-0.1)
    except ValueError as e:
        assert "lambda_normal_prior" in str(e)
    else:
        raise AssertionError("a negative weight was accepted")
