"""Given-view steps on a random background: the target is re-composited on the colour the avatar is
rendered over (the person's pixels kept), a new colour each step; the evaluation's background and
old run records are unchanged."""

import numpy as np
import torch

from reconstruct.train import steps as steps_module
from reconstruct.train.config import Stage1Config
from reconstruct.train.data import FrameTarget, composite_on
from reconstruct.train.trainer import Trainer


def test_composite_on_matches_compositing_from_the_premultiplied_image():
    rng = np.random.default_rng(0)
    person = rng.random((5, 7, 3))
    mask = rng.random((5, 7))
    mask[0, :] = 0.0
    mask[1, :] = 1.0
    black, red = np.zeros(3), np.array([0.9, 0.1, 0.2])
    premult = person * mask[..., None]  # how frames are stored: over black
    grey = np.array([0.5, 0.5, 0.5])
    over_grey = premult + (1 - mask[..., None]) * grey
    t = FrameTarget(None, torch.tensor(over_grey, dtype=torch.float32), torch.tensor(mask, dtype=torch.float32),
                    None, (0, 0, 7, 5))
    got = composite_on(t, torch.tensor(red, dtype=torch.float32), torch.tensor(grey, dtype=torch.float32)).double().numpy()
    want = premult + (1 - mask[..., None]) * red
    assert np.abs(got - want).max() < 1e-6
    assert np.allclose(got[0], red) and np.allclose(got[1], premult[1], atol=1e-6)
    assert np.abs(composite_on(t, torch.tensor(black, dtype=torch.float32), torch.tensor(grey, dtype=torch.float32)).numpy()
                  - premult).max() < 1e-6


def _record_steps(trainer, n, monkeypatch):
    seen = []
    real_render, real_mse = steps_module.render_avatar, steps_module.L.mse

    def render(posed, camera, background, **kw):
        seen.append({"background": background.clone()})
        return real_render(posed, camera, background, **kw)

    def mse(a, b):
        if "target" not in seen[-1]:
            seen[-1]["target"] = b.detach().clone()
        return real_mse(a, b)

    monkeypatch.setattr(steps_module, "render_avatar", render)
    monkeypatch.setattr(steps_module.L, "mse", mse)
    for _ in range(n):
        trainer.step()
    return seen


def test_each_step_renders_and_compares_on_the_same_random_colour(tiny_scene, tiny_config, monkeypatch):
    t = Trainer(tiny_scene, tiny_config)
    assert tiny_config.random_background
    seen = _record_steps(t, 3, monkeypatch)
    bgs = torch.stack([s["background"] for s in seen])
    assert bgs.shape == (3, 3) and (bgs.std(0) > 1e-3).all()  # a new colour each step
    for s in seen:
        target, bg = s["target"], s["background"]
        # pixels the person does not cover show the step's colour; covered ones the person
        matched = False
        for tg in t.data.targets.values():
            if tg.image.shape != target.shape:
                continue
            out, full = tg.mask == 0, tg.mask == 1
            if torch.allclose(target[full], tg.image[full]) and torch.allclose(target[out], bg.expand_as(target[out])):
                matched = True
        assert matched


def test_fixed_background_when_switched_off_and_for_old_records(tiny_scene, tiny_config, monkeypatch):
    cfg = Stage1Config.from_dict({**tiny_config.to_dict(), "random_background": False})
    t = Trainer(tiny_scene, cfg)
    seen = _record_steps(t, 2, monkeypatch)
    assert all(torch.equal(s["background"], t.background) for s in seen)
    rec = Stage1Config().to_dict()
    del rec["random_background"]
    assert not Stage1Config.from_dict(rec).random_background
    assert not Stage1Config.paper().random_background
