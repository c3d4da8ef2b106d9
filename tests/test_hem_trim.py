"""Trimming the garment layer's hem part way through Stage I (``train/hem_trim.py``,
``AvatarModel.trim_layer``, ``Stage1Config.layer_hem_trims``; docs/loose_clothing.md, "The layer
trimmed at the hem"): trimmed Gaussians draw nothing and learn nothing, in this stage, the next and
after a checkpoint; each trim runs once, at its fraction of the stage, on what the hem rule finds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from reconstruct.avatar import AvatarConfig
from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, landmark_heights
from reconstruct.body.parts import PART_INDEX
from reconstruct.train.render import render_avatar

LEGS = ("thigh.L", "thigh.R", "shin.L", "shin.R")


def _layer(body):
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)
    return build_garment_layer(body, hint, cols=16, row_step=0.06)


@pytest.fixture
def layered(tiny_scene, tiny_config):
    from reconstruct.train.trainer import Trainer

    body = tiny_scene.body_model()
    return Trainer(tiny_scene, tiny_config, None, garment_layer=_layer(body))


def _bottom_front(model) -> torch.Tensor:
    N = model.num_body
    R = model.layer.grid_shape[0]
    y = model.base_positions[N:, 1]
    return (model.layer_rc[:, 0] == R - 1) & (y < y.mean())


def test_trimmed_gaussians_are_transparent_get_no_gradient_and_the_rest_are_unchanged(layered):
    m = layered.model
    N = m.num_body
    flags = _bottom_front(m)
    assert 0 < int(flags.sum()) < m.num_layer
    with torch.no_grad():
        m.layer_opacity.normal_(0.0, 0.3)  # every opacity away from 0 before the trim
    before = m.opacities().detach().clone()
    assert m.trim_layer(flags) == int(flags.sum())
    assert m.trim_layer(flags) == 0  # trimmed already: none new
    after = m.opacities()
    assert torch.equal(after[N:][flags], torch.zeros(int(flags.sum())))
    assert torch.equal(after[N:][~flags], before[N:][~flags]) and torch.equal(after[:N], before[:N])
    # rendered: nothing of theirs reaches the image, and their parameters get no gradient
    c = m.canonical()
    cam = layered.data.targets[layered.data.frames[0]].camera
    r = render_avatar(m.splats(c), cam, torch.zeros(3), normals=False)
    (r.alpha.sum() + r.rgb.sum()).backward()
    grad = m.layer_opacity.grad
    assert torch.equal(grad[flags], torch.zeros(int(flags.sum())))
    assert float(grad[~flags].abs().sum()) > 0
    with pytest.raises(ValueError, match="trim_layer: flags must have shape"):
        m.trim_layer(torch.zeros(m.num_layer + 1, dtype=torch.bool))


def test_trim_layer_hem_trims_what_the_hem_rule_finds_and_unsees_it(layered, monkeypatch):
    from reconstruct.train import hem_trim

    t = layered
    m = t.model
    N = m.num_body
    for _ in range(2):
        t.step()
    flags = _bottom_front(m)
    got = {}

    def rule(model, seen, colors):  # finds the bottom front's even columns, then all of it
        got.setdefault("seen", torch.as_tensor(seen).clone())
        got.setdefault("colors", torch.as_tensor(colors).clone())
        got["calls"] = got.get("calls", 0) + 1
        out = np.zeros(model.num_gaussians, bool)
        out[N:] = (flags & (torch.arange(len(flags)) % 2 == 0) if got["calls"] == 1 else flags).numpy()
        return out

    monkeypatch.setattr(hem_trim, "model_layer_shows_body", rule)
    t.state.seen[N:] = True
    seen_before = t.state.seen.clone()
    assert hem_trim.trim_layer_hem(t.state) == int(flags.sum())
    assert got["calls"] == 3  # even columns, the rest, nothing new
    # the rule read the seen flags and the canonical colours first
    assert torch.equal(got["seen"], seen_before)
    with torch.no_grad():
        assert torch.allclose(got["colors"], m.canonical(None).colors.cpu())
    assert torch.equal(m.layer_trimmed, flags)
    assert torch.equal(t.state.seen[N:], ~flags) and torch.equal(t.state.seen[:N], seen_before[:N])


def test_the_hem_rule_on_painted_legs_trims_the_bottom_row_in_front(layered, monkeypatch):
    """End to end through the real hem rule: skin legs, grey cloth, the seen bottom row in front
    painted like the legs (what a layer longer than the garment learns) is trimmed, nothing else."""
    from reconstruct.train import hem_trim

    m = layered.model
    N, M = m.num_body, m.num_layer
    parts = m.parts()
    skin, grey = torch.tensor([0.66, 0.5, 0.45]), torch.tensor([0.45, 0.45, 0.47])
    colours = grey.repeat(N + M, 1)
    colours[:N][torch.as_tensor(np.isin(parts[:N], [PART_INDEX[p] for p in LEGS]))] = skin
    front = m.base_positions[N:, 1] < m.base_positions[N:, 1].mean()
    hem = _bottom_front(m)
    colours[N:][hem] = skin
    real = m.canonical

    def painted(*a, **kw):
        return dataclasses.replace(real(*a, **kw), colors=colours.clone())

    monkeypatch.setattr(m, "canonical", painted)
    layered.state.seen[:] = True
    layered.state.seen[N:] = front
    n = hem_trim.trim_layer_hem(layered.state)
    assert n == int(m.layer_trimmed.sum()) and n > 0.9 * int(hem.sum())
    assert not bool((m.layer_trimmed & ~hem).any())


def test_stage1_trims_at_its_fractions_once_each_and_the_trims_last(tiny_scene, tiny_config, tmp_path, monkeypatch):
    from reconstruct.train import plan as plan_module
    from reconstruct.train.checkpoint import load_checkpoint
    from reconstruct.train.trainer import Trainer

    body = tiny_scene.body_model()
    config = dataclasses.replace(tiny_config, iters=8, layer_hem_trims=(0.25, 0.5))
    t = Trainer(tiny_scene, config, None, garment_layer=_layer(body))
    bottom = _bottom_front(t.model)
    picks = [bottom & (torch.arange(len(bottom)) % 2 == k) for k in (0, 1)]  # what each trim finds
    calls = []

    def trim(state):
        calls.append(current[0].stage_step)
        return state.model.trim_layer(picks[len(calls) - 1])

    current = [t]
    monkeypatch.setattr(plan_module, "trim_layer_hem", trim)
    t.step()
    assert calls == []
    t.step()  # the 2nd of 8 steps reaches a quarter
    assert calls == [2] and torch.equal(t.model.layer_trimmed, picks[0])
    t.step()
    path = t.save(tmp_path / "checkpoint.pt")  # between the two trims
    t.step()  # one half
    assert calls == [2, 4] and torch.equal(t.model.layer_trimmed, bottom)
    for _ in range(2):
        t.step()
    assert calls == [2, 4]  # once each
    assert torch.equal(t.model.opacities()[t.model.num_body:][bottom], torch.zeros(int(bottom.sum())))
    # resumed between them: the first is in the checkpoint and not redone, the second is done
    state = load_checkpoint(path)
    t2 = Trainer(tiny_scene, config, None, garment_layer=_layer(body))
    t2.load_state_dict(state, str(path))
    current[0] = t2
    assert torch.equal(t2.model.layer_trimmed, picks[0])
    calls.clear()
    calls.append("resumed")  # the next trim reads picks[1]
    t2.step()
    assert calls == ["resumed", 4] and torch.equal(t2.model.layer_trimmed, bottom)
    # a trim the resumed run's first step crosses is done, though that step passes it (at 0.5 of
    # the stage: a trim at 0.45 was not done before the checkpoint at 0.375)
    config45 = dataclasses.replace(config, layer_hem_trims=(0.25, 0.45))
    t4 = Trainer(tiny_scene, config45, None, garment_layer=_layer(body))
    t4.load_state_dict(state, str(path))
    current[0] = t4
    calls[:] = ["resumed"]
    t4.step()
    assert calls == ["resumed", 4] and torch.equal(t4.model.layer_trimmed, bottom)
    # a checkpoint from before trimming existed loads with nothing trimmed
    del state["avatar"]["model"]["layer_trimmed"]
    t3 = Trainer(tiny_scene, config, None, garment_layer=_layer(body))
    t3.load_state_dict(state, str(path))
    assert not bool(t3.model.layer_trimmed.any())


def test_the_setting_defaults_old_records_and_bad_values():
    from reconstruct.train.config import Stage1Config

    assert Stage1Config().layer_hem_trims == (0.4, 0.7)
    assert Stage1Config.paper().layer_hem_trims == ()
    assert Stage1Config.from_dict({}).layer_hem_trims == ()
    for bad in ((0.0,), (1.0,), (-0.2, 0.5), (0.6, 0.4), (0.5, 0.5)):
        with pytest.raises(ValueError, match="layer_hem_trims must be increasing fractions"):
            Stage1Config(layer_hem_trims=bad)
    cfg = Stage1Config(avatar=AvatarConfig())
    assert tuple(Stage1Config.from_dict(cfg.to_dict()).layer_hem_trims) == (0.4, 0.7)
