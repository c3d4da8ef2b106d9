"""Stage I's unseen fill (reconstruct/train/unseen_fill.py): never-seen Gaussians decode to the
wrap-around fill's colours, everything else is left as it was, and the trainer runs it once when
Stage I ends."""

import numpy as np
import pytest
import torch

from reconstruct.appearance.propagation import erode, erode_by_part
from reconstruct.appearance.wrap_fill import wrap_fill_colors
from reconstruct.body.uv_map import texel_neighbours
from reconstruct.train.unseen_fill import fill_unseen_colors


@pytest.fixture
def trainer(tiny_scene, tiny_config, tmp_path):
    from reconstruct.train.trainer import Trainer

    t = Trainer(tiny_scene, tiny_config, tmp_path / "run")
    for _ in range(6):
        t.step()
    return t


def _decoded(model):
    with torch.no_grad():
        c = model.canonical(None)
    return {"colors": c.colors.clone(), "means": c.means.clone(), "scales": c.scales.clone()}


@pytest.mark.parametrize("ring", [0, 1])
def test_unseen_gaussians_decode_to_the_fill_and_nothing_else_moves(trainer, ring):
    state, model = trainer.state, trainer.model
    seen = state.seen.clone()
    assert 0 < int(seen.sum()) < len(seen), "the tiny run must see part of the body"
    before = _decoded(model)
    nb = texel_neighbours(model.uv_map.texel_rc, model.uv_map.resolution)
    trusted = torch.as_tensor(erode_by_part(seen.numpy(), nb, model.parts(), 2))
    expected = wrap_fill_colors(model.base_positions.cpu(), model.parts(), trusted, before["colors"], nb,
                                normals=model.base_normals.cpu())
    n = fill_unseen_colors(state, keep_ring=ring)
    after = _decoded(model)
    todo = torch.as_tensor(erode((~seen).numpy(), nb, ring)) if ring else ~seen
    assert n == int(todo.sum()) > 0
    # the filled Gaussians decode to the fill's colours (through the logit and the residual's gain)
    assert (after["colors"][todo] - expected[todo]).abs().max() < 1e-4
    # and they changed: the fill is not the decoder's guess
    assert (before["colors"][todo] - expected[todo]).abs().max() > 0.05
    # seen ones and the ring kept by keep_ring are bit-identical, geometry untouched
    assert torch.equal(after["colors"][~todo], before["colors"][~todo])
    assert torch.equal(after["means"], before["means"]) and torch.equal(after["scales"], before["scales"])


def test_ring_keeps_only_the_colours_training_shaped(trainer):
    """``ring_trained``: an unseen Gaussian of the kept ring that training never shaped (a garment
    layer's back beside a seen edge) takes the fill's colour like the rest; the trained part of the
    ring keeps its decoded colour bit-identically."""
    state, model = trainer.state, trainer.model
    seen = state.seen.clone()
    nb = texel_neighbours(model.uv_map.texel_rc, model.uv_map.resolution)
    trusted = torch.as_tensor(erode_by_part(seen.numpy(), nb, model.parts(), 2))
    before = _decoded(model)
    expected = wrap_fill_colors(model.base_positions.cpu(), model.parts(), trusted, before["colors"], nb,
                                normals=model.base_normals.cpu())
    ring = (~seen) & ~torch.as_tensor(erode((~seen).numpy(), nb, 1))
    ring_ids = torch.nonzero(ring)[:, 0]
    assert len(ring_ids) >= 4, "the tiny run must have a ring of unseen Gaussians round the seen ones"
    untrained = torch.zeros_like(seen)
    untrained[ring_ids[::2]] = True  # every other ring Gaussian: never shaped by training
    n = fill_unseen_colors(state, keep_ring=1, ring_trained=~untrained)
    after = _decoded(model)
    todo = torch.as_tensor(erode((~seen).numpy(), nb, 1)) | untrained
    assert n == int(todo.sum())
    assert (after["colors"][untrained] - expected[untrained]).abs().max() < 1e-4
    assert (before["colors"][untrained] - expected[untrained]).abs().max() > 0.02
    kept = ring & ~untrained
    assert torch.equal(after["colors"][kept], before["colors"][kept])
    assert torch.equal(after["colors"][seen], before["colors"][seen])
    with pytest.raises(ValueError, match="ring_trained must have shape"):
        fill_unseen_colors(state, keep_ring=1, ring_trained=torch.ones(len(seen) - 1, dtype=torch.bool))


def test_painted_visibility_is_respected(trainer):
    from reconstruct.edits import PaintSeen
    from reconstruct.edits.session import EditSession

    state = trainer.state
    unseen = np.flatnonzero(~state.seen.numpy())
    painted = unseen[: len(unseen) // 2]
    session = EditSession(state, autosave=False, load=False)
    session.selection = np.zeros(state.num_gaussians, bool)
    session.selection[painted] = True
    session.apply(PaintSeen())
    before = _decoded(trainer.model)["colors"]
    fill_unseen_colors(state, keep_ring=0)
    after = _decoded(trainer.model)["colors"]
    assert torch.equal(after[painted], before[painted])  # painted seen: not filled
    rest = unseen[len(unseen) // 2:]
    assert (after[rest] - before[rest]).abs().max() > 0.05


def test_trainer_fills_once_at_the_end_of_stage1(tiny_scene, tiny_config, tmp_path, monkeypatch):
    from reconstruct.train import plan as plan_module
    from reconstruct.train.trainer import Trainer

    calls = []
    real = plan_module.fill_unseen_colors
    from reconstruct.train.seen_recount import untrained_colours

    touched = []  # the colours training touched, when the fill is called
    seen_then = []
    monkeypatch.setattr(plan_module, "fill_unseen_colors",
                        lambda state, **kw: touched.append(~untrained_colours(state.model)) or calls.append(kw)
                        or seen_then.append(state.seen.clone()) or real(state, **kw))
    tiny_config.iters = 5
    t = Trainer(tiny_scene, tiny_config, tmp_path / "run")
    for _ in range(4):
        t.step()
    assert calls == []
    t.step()
    # trained on random backgrounds: grazing seen colours are sources (grazing_rule_for); those
    # seen by their blend weight alone are not (a bool per Gaussian)
    assert t.done and len(calls) == 1
    not_sources = calls[0].pop("not_sources")
    views = calls[0].pop("hair_views")  # the training frames, read by the fill only for a head showing hair
    assert iter(views) is views
    # the tiny scene has no garment layer: the ring of the body keeps its decoded colours but where
    # the arms hid it (``body_hidden_by_limbs``: those are unseen); no seen Gaussian is one whose
    # colour training never touched (``seen_trained_only``); no layer gaps to read round
    ring = calls[0].pop("ring_trained")
    assert ring is None or (ring.dtype == torch.bool and not bool((~ring & seen_then[0].cpu()).any()))
    assert calls == [{"keep_ring": tiny_config.fill_unseen_ring, "grazing_rule": False,
                      "layer_gaps": None, "layer_gap_reach": tiny_config.layer_gap_reach}]
    assert bool((~touched[0]).any()) and not bool((t.state.seen & ~touched[0]).any())
    assert not_sources.dtype == torch.bool and not_sources.shape == (t.state.num_gaussians,)
    assert not (not_sources & ~t.state.seen).any()
    t.step()  # a step past the end (the studio's single step) does not fill again
    assert len(calls) == 1


def test_hair_views_are_training_frames_posed_with_their_images(tiny_scene, tiny_config, tmp_path):
    from reconstruct.train.trainer import Trainer
    from reconstruct.train.unseen_fill import hair_views_of

    t = Trainer(tiny_scene, tiny_config, tmp_path / "run")
    views = list(hair_views_of(t.state, t.data, max_frames=2))
    frames = list(t.data.frames)
    assert len(views) == min(2, len(frames)) and len(frames) > 2
    first = tiny_scene.frames[frames[0]]
    uv, z = first.camera.project(t.state.posed(frames[0]).means.detach().double().numpy())
    np.testing.assert_allclose(views[0].uv, uv)
    assert views[0].in_front.all() and views[0].image is first.image and views[0].mask is first.mask


def test_paper_settings_and_older_runs_do_not_fill():
    from reconstruct.train.config import Stage1Config

    assert Stage1Config().fill_unseen and not Stage1Config.paper().fill_unseen
    old = Stage1Config().to_dict()
    del old["fill_unseen"]
    assert not Stage1Config.from_dict(old).fill_unseen


def test_grazing_rule_only_for_a_fixed_background(trainer, monkeypatch):
    from reconstruct.appearance.wrap_fill import grazing_rule_for
    from reconstruct.train import unseen_fill
    from reconstruct.train.config import Stage1Config

    assert not grazing_rule_for(Stage1Config()) and grazing_rule_for(Stage1Config.paper())
    old = Stage1Config().to_dict()
    del old["random_background"]
    assert grazing_rule_for(Stage1Config.from_dict(old))
    seen_normals = []
    real = unseen_fill.wrap_fill_colors

    def spy(*a, **kw):
        seen_normals.append(kw.get("normals"))
        return real(*a, **kw)

    monkeypatch.setattr(unseen_fill, "wrap_fill_colors", spy)
    fill_unseen_colors(trainer.state, keep_ring=1, grazing_rule=True)
    fill_unseen_colors(trainer.state, keep_ring=1, grazing_rule=False)
    assert seen_normals[0] is not None and seen_normals[1] is None
