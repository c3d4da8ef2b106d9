"""The end-of-Stage-I recount's blend weights: a Gaussian the training images blended into the
person's pixels is seen (first hit or not), so the unseen fill does not repaint what the images
fitted; a garment-layer Gaussian the training rays reached keeps its trained opacity."""

import dataclasses

import pytest
import torch

from reconstruct.avatar.config import AvatarConfig
from reconstruct.train.config import Stage1Config
from reconstruct.train.render import render_avatar
from reconstruct.train.seen_recount import (MIN_PERSON_SHARE, PERSON, blended_on_person, keep_seen_on_person,
                                            person_coverage)
from reconstruct.train.trainer import Trainer

_SMALL = AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                      hidden=32)


def _trained(scene, steps=12, **kw):
    cfg = Stage1Config(iters=30, eval_every_seconds=1e9, checkpoint_every_seconds=1e9, crop_margin=4, avatar=_SMALL,
                       **kw)
    t = Trainer(scene, cfg)
    for _ in range(steps):
        t.step()
    return t


@pytest.fixture(scope="module")
def one_photo():
    """The tiny scene's person in a single frame: most of what draws it is no first hit."""
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    return build_synthetic_scene(SyntheticConfig(seed=1, num_frames=1, image_size=64, num_eval_azimuths=8,
                                                 eval_frames=1, texture_size=128), progress=False)


def _one_hot_sums(t, ids: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Reference without autograd: each Gaussian of ``ids`` alone coloured 1 in one channel, on a
    black background; the image's sum over person pixels and over all pixels, over the frames."""
    person, total = torch.zeros(len(ids), dtype=torch.float64), torch.zeros(len(ids), dtype=torch.float64)
    for start in range(0, len(ids), 3):
        chunk = ids[start:start + 3]
        for i in t.data.frames:
            tgt = t.data.targets[i]
            with torch.no_grad():
                posed = t.state.posed(i)
                colors = torch.zeros_like(posed.colors)
                for c, g in enumerate(chunk):
                    colors[g, c] = 1.0
                rgb = render_avatar(dataclasses.replace(posed, colors=colors), tgt.camera, torch.zeros(3),
                                    normals=False).rgb.double()
            m = (tgt.mask > PERSON).double()
            for c in range(len(chunk)):
                person[start + c] += (rgb[..., c] * m).sum()
                total[start + c] += rgb[..., c].sum()
    return person, total


def test_blend_weights_match_one_hot_renders(tiny_scene):
    t = _trained(tiny_scene)
    cov = person_coverage(t.state, t.data, weights=True)
    assert cov.weight.shape == cov.total.shape == (t.state.num_gaussians,)
    assert torch.all(cov.weight <= cov.total + 1e-6) and float(cov.weight.sum()) > 0
    order = torch.argsort(cov.weight, descending=True)
    gen = torch.Generator().manual_seed(0)
    some = torch.nonzero(cov.total > 1e-3).squeeze(1)
    ids = [int(g) for g in order[:6]] + [int(g) for g in some[torch.randperm(len(some), generator=gen)[:6]]]
    person, total = _one_hot_sums(t, ids)
    assert torch.allclose(cov.weight[ids], person, rtol=1e-4, atol=1e-5)
    assert torch.allclose(cov.total[ids], total, rtol=1e-4, atol=1e-5)
    # the first hits are those of the recount without weights
    assert torch.equal(cov.first_hits, person_coverage(t.state, t.data).first_hits)


def test_blended_gaussians_become_seen_and_the_share_rule(one_photo):
    t = _trained(one_photo)
    cov = person_coverage(t.state, t.data, weights=True)
    blended = blended_on_person(cov, 0.05)
    # the point: Gaussians the image blended in with some weight that are no first hit
    assert int((blended & (cov.first_hits == 0)).sum()) > 0
    before = t.state.seen.clone()
    k = keep_seen_on_person(t.state, t.data, min_weight=0.05)
    on = (cov.first_hits > 0) | blended
    assert torch.equal(t.state.seen, before & on | on & ~before)
    assert k.dropped == int((before & ~on).sum()) and k.added == int((on & ~before).sum()) > 0
    # without weights: first hits only, nothing added
    t2 = _trained(one_photo)
    seen2 = t2.state.seen.clone()
    assert keep_seen_on_person(t2.state, t2.data).added == 0
    assert torch.equal(t2.state.seen, seen2 & (cov.first_hits > 0))
    # the share rule: with the person cut to the mask's left half, a Gaussian blended mostly into
    # the right half is not marked, however large its weight on the left
    for tgt in t.data.targets.values():
        tgt.mask[:, tgt.mask.shape[1] // 2:] = 0.0
    cut = person_coverage(t.state, t.data, weights=True)
    t.state.seen.zero_()
    keep_seen_on_person(t.state, t.data, min_weight=0.05, coverage=cut)
    added = t.state.seen & (cut.first_hits == 0)
    assert added.any()
    assert torch.all(cut.weight[added] >= MIN_PERSON_SHARE * cut.total[added] - 1e-9)
    mostly_right = (cut.weight >= 0.05) & (cut.weight < MIN_PERSON_SHARE * cut.total) & (cut.first_hits == 0)
    assert mostly_right.any() and not (t.state.seen & mostly_right).any()
    with pytest.raises(ValueError, match="without weights"):
        blended_on_person(person_coverage(t.state, t.data), 0.05)


def test_the_fill_keeps_the_training_view_of_one_photo(one_photo):
    """The end of Stage I on a single frame: with the blend weights, the fill repaints much less of
    what the photo fitted (first hits alone: 5x the change on the person's pixels)."""
    change = {}
    for w in (None, 0.05):
        t = _trained(one_photo, steps=25, seen_min_weight=w)
        i = t.data.frames[0]
        tgt = t.data.targets[i]

        def render():
            with torch.no_grad():
                return render_avatar(t.state.posed(i), tgt.camera, torch.zeros(3), normals=False).rgb

        a = render()
        note = t.plan.finish(t)
        b = render()
        change[w] = float((a - b).abs().mean(-1)[tgt.mask > PERSON].mean())
        assert ("blended into the person" in note) == (w is not None)
    assert change[0.05] < 0.4 * change[None]


def test_layer_reached_is_weight_over_opacity(tiny_scene, tiny_config):
    """Against renders with one layer Gaussian made opaque: its blend weight then is what the rays
    bring to it (transmittance times footprint), which ``layer_reached`` reads as weight / opacity."""
    from test_garment_layer_avatar import _layer, _trainer

    from reconstruct.train.unseen_fill import layer_reached

    t = _trainer(tiny_scene, tiny_config, _layer(tiny_scene.body_model()))
    for _ in range(3):
        t.step()
    m = t.model
    N = m.num_body
    with torch.no_grad():  # opacities well inside (0, 1), so that alpha stays below its clamp
        m.layer_opacity.copy_(torch.logit(torch.full_like(m.layer_opacity, 0.3)) / m.config.garment_opacity_gain)
    cov = person_coverage(t.state, t.data, weights=True)
    reach = cov.total[N:] / 0.3
    ids = [int(g) for g in torch.argsort(reach, descending=True)[:4]]
    ref = []
    for g in ids:
        with torch.no_grad():
            saved = m.layer_opacity[g].clone()
            m.layer_opacity[g] = 40.0 / m.config.garment_opacity_gain
            _, total = _one_hot_sums(t, [N + g])
            m.layer_opacity[g] = saved
        ref.append(float(total[0]))
    # opaque, the Gaussian's footprint saturates at alpha's clamp (0.99) near its centre
    assert torch.allclose(reach[ids], torch.tensor(ref, dtype=torch.float64), rtol=0.05)
    reached = layer_reached(t.state, cov.total, 0.05)
    assert torch.equal(reached, reach >= 0.05) and reached.any() and not reached.all()


def test_setting_defaults_old_records_and_bad_values():
    assert Stage1Config().seen_min_weight == 0.05
    assert Stage1Config.paper().seen_min_weight is None
    rec = Stage1Config().to_dict()
    del rec["seen_min_weight"]
    assert Stage1Config.from_dict(rec).seen_min_weight is None
    with pytest.raises(ValueError, match="seen_min_weight"):
        Stage1Config(seen_min_weight=0.0)
