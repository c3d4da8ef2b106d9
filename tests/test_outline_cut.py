"""The garment layer's Gaussians the person's outline cut away (``AvatarModel.layer_outline_cut``,
``unseen_fill.mark_outline_cut``): Stage I's finish marks the transparent ones a training frame
shows on the background, checkpoints keep the marks, and the body under them counts as the
cloth's (``layer_cover.model_body_under_layer``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from reconstruct.avatar.layer_cover import model_body_under_layer
from reconstruct.train.config import Stage1Config


@pytest.fixture
def layered(tiny_scene, tiny_config):
    from tests.test_garment_layer_avatar import _layer, _trainer

    return _trainer(tiny_scene, tiny_config, _layer(tiny_scene.body_model()))


def _side_columns(model) -> torch.Tensor:
    """(M,) bool: a quarter of the layer's columns, every row but the top."""
    rc = model.layer_rc
    C = model.layer.grid_shape[1]
    return (rc[:, 1] >= C // 8) & (rc[:, 1] < C // 8 + C // 4) & (rc[:, 0] >= 1)


def _set_opacity(model, transparent: torch.Tensor) -> None:
    with torch.no_grad():
        logit = torch.where(transparent, torch.tensor(-4.0), torch.tensor(4.0))
        model.layer_opacity.copy_(logit / model.config.garment_opacity_gain)


def test_the_finish_marks_transparent_layer_gaussians_a_frame_shows_on_the_background(layered, monkeypatch):
    """Marked: off the person in some frame (``off_person``, given here), under 0.5 opacity, not
    trimmed. Opaque ones off the person, transparent ones over it, and trimmed ones are not. The
    note says how many; with the setting off (and for runs recorded before it) none is marked."""
    from reconstruct.train import plan as plan_module

    t = layered
    m = t.model
    M = m.num_layer
    side = _side_columns(m)
    _set_opacity(m, side)
    off = side.clone()
    off[torch.arange(M) % 5 == 0] = False  # over the person in every frame
    off |= ~side & (torch.arange(M) % 7 == 0)  # off the person but opaque
    trimmed = side & (torch.arange(M) % 11 == 0)
    m.trim_layer(trimmed)
    real = plan_module.layer_training_views

    def views(state, data, **kw):
        out = real(state, data, **kw)
        assert "off_person" in out
        out["off_person"] = off.clone()
        return out

    monkeypatch.setattr(plan_module, "layer_training_views", views)
    want = off & side & ~trimmed
    t.plan.settings = dataclasses.replace(t.plan.settings, layer_outline_cut=False)
    t.plan.finish(t)
    assert not bool(m.layer_outline_cut.any())
    t.plan.settings = dataclasses.replace(t.plan.settings, layer_outline_cut=True)
    note = t.plan.finish(t)
    assert torch.equal(m.layer_outline_cut, want) and int(want.sum()) > 10
    assert f"{int(want.sum())} garment-layer Gaussians training emptied past the person's outline" in note
    assert Stage1Config.from_dict({}).layer_outline_cut is False
    assert Stage1Config().layer_outline_cut is True and Stage1Config.paper().layer_outline_cut is False


def test_the_body_under_a_cut_side_is_the_cloths(layered):
    """A quarter of the columns emptied from the second row down hides nothing under them; marked
    cut, the body under them is hidden (by Gaussians of those columns), as under the opaque cloth
    beside them; the rest is unchanged."""
    m = layered.model
    N = m.num_body
    side = _side_columns(m)
    _set_opacity(m, torch.zeros_like(side))
    full = model_body_under_layer(m)
    _set_opacity(m, side)
    emptied = model_body_under_layer(m)
    under_side = (full[:N] >= 0) & side[np.clip(full[:N] - N, 0, None)].numpy()
    assert under_side.sum() > 20
    assert (emptied[:N][under_side] == -1).all()
    m.mark_outline_cut(side)
    marked = model_body_under_layer(m)
    np.testing.assert_array_equal(marked, full)
    with pytest.raises(ValueError, match=r"mark_outline_cut: flags must have shape \(%d,\)" % m.num_layer):
        m.mark_outline_cut(side[:-1])


def test_checkpoints_keep_the_marks_and_old_ones_load_without(layered, tiny_scene, tiny_config, tmp_path):
    from reconstruct.train.checkpoint import load_checkpoint
    from tests.test_garment_layer_avatar import _trainer

    t = layered
    flags = _side_columns(t.model) & (torch.arange(t.model.num_layer) % 3 == 0)
    t.model.mark_outline_cut(flags)
    path = t.save(tmp_path / "checkpoint.pt")
    state = load_checkpoint(path)
    t2 = _trainer(tiny_scene, tiny_config, t.model.layer)
    t2.load_state_dict(state, str(path))
    assert torch.equal(t2.model.layer_outline_cut, flags)
    del state["avatar"]["model"]["layer_outline_cut"]  # a checkpoint saved before the marks
    t3 = _trainer(tiny_scene, tiny_config, t.model.layer)
    t3.load_state_dict(state, str(path))
    assert not bool(t3.model.layer_outline_cut.any())
