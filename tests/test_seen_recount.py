"""Stage I's seen flags recounted on the person at the end of the stage: a seen Gaussian stays
seen only if it is the facing first hit of a pixel the mask gives to the person."""

import numpy as np
import torch

from reconstruct.train.config import Stage1Config
from reconstruct.train.render import render_avatar
from reconstruct.train.seen_recount import PERSON, keep_seen_on_person, person_first_hits
from reconstruct.train.trainer import Trainer


def _trained(tiny_scene, tiny_config, **kw):
    t = Trainer(tiny_scene, Stage1Config.from_dict({**tiny_config.to_dict(), **kw}))
    for _ in range(12):
        t.step()
    return t


def _naive_counts(t) -> np.ndarray:
    """Pixel by pixel: facing first hits on person pixels."""
    n = t.state.num_gaussians
    out = np.zeros(n, np.int64)
    with torch.no_grad():
        for i in t.data.frames:
            tgt = t.data.targets[i]
            posed = t.state.posed(i)
            r = render_avatar(posed, tgt.camera, t.background, normals=False, first_hit=True, hit_threshold=0.5)
            hit = r.first_hit.numpy()
            mask = tgt.mask.numpy()
            means, normals = posed.means.numpy().astype(np.float64), posed.normals.numpy().astype(np.float64)
            c = np.asarray(tgt.camera.center, np.float64)
            for (y, x), g in np.ndenumerate(hit):
                if g >= 0 and mask[y, x] > PERSON and np.dot(means[g] - c, normals[g]) < 0:
                    out[g] += 1
    return out


def test_counts_match_a_pixel_by_pixel_count(tiny_scene, tiny_config):
    t = _trained(tiny_scene, tiny_config)
    got = person_first_hits(t.state, t.data).numpy()
    want = _naive_counts(t)
    assert got.sum() > 0 and np.array_equal(got, want)


def test_seen_only_off_the_person_becomes_unseen(tiny_scene, tiny_config):
    t = _trained(tiny_scene, tiny_config)
    before = t.state.seen.clone()
    assert before.any()
    # cut the person's mask to its left half in every frame: what only the right half showed goes
    for tgt in t.data.targets.values():
        tgt.mask[:, tgt.mask.shape[1] // 2:] = 0.0
    on_left = person_first_hits(t.state, t.data) > 0
    k = keep_seen_on_person(t.state, t.data).dropped
    assert k == int((before & ~on_left).sum()) and k > 0
    assert torch.equal(t.state.seen, before & on_left)
    # with no person anywhere nothing stays seen
    for tgt in t.data.targets.values():
        tgt.mask.zero_()
    still = int(t.state.seen.sum())
    assert still > 0 and keep_seen_on_person(t.state, t.data).dropped == still
    assert not t.state.seen.any()


def test_end_of_stage_one_recounts_only_when_asked(tiny_scene, tiny_config):
    # first hits only (the blend weights' additions: test_seen_blend_weights.py)
    on = _trained(tiny_scene, tiny_config, fill_unseen=False, seen_min_weight=None)
    off = _trained(tiny_scene, tiny_config, fill_unseen=False, seen_on_person=False, seen_min_weight=None)
    assert torch.equal(on.state.seen, off.state.seen)  # training never reads the flags
    for t in (on, off):
        for tgt in t.data.targets.values():
            tgt.mask[:, : tgt.mask.shape[1] // 2] = 0.0
    seen = off.state.seen.clone()
    off.plan.finish(off)
    assert torch.equal(off.state.seen, seen)
    note = on.plan.finish(on)
    assert (on.state.seen & ~seen).sum() == 0 and int(on.state.seen.sum()) < int(seen.sum())
    assert note and "off the person" in note
    assert not Stage1Config.paper().seen_on_person
    rec = Stage1Config().to_dict()
    del rec["seen_on_person"]
    assert not Stage1Config.from_dict(rec).seen_on_person


def test_seen_gaussians_training_never_coloured_are_unseen(tiny_scene, tiny_config):
    """The premise: a Gaussian's colour residual leaves zero on the first step that gives it a colour
    gradient and not before (Adam, from zeros), so an all-zero row is a colour training never
    touched. ``unsee_untrained`` unmarks exactly the seen ones among those; a model without the
    residual tells nothing."""
    from reconstruct.train.seen_recount import unsee_untrained, untrained_colours

    t = Trainer(tiny_scene, tiny_config)
    residual = t.model.decoder.color_residual
    assert bool(untrained_colours(t.model).all())  # nothing trained yet
    t.step()
    touched = (residual.grad != 0).any(1).cpu()
    assert 0 < int(touched.sum()) < len(touched)
    np.testing.assert_array_equal(untrained_colours(t.model).numpy(), ~touched.numpy())
    for _ in range(5):
        t.step()
    untrained = untrained_colours(t.model)
    seen = t.state.seen.clone()
    assert bool((seen & ~untrained).any())
    # make some seen Gaussians untouched again: they, and only they, become unseen
    pick = torch.nonzero(seen & ~untrained).squeeze(1)[::3]
    with torch.no_grad():
        residual[pick] = 0.0
    want = seen & untrained_colours(t.model)
    assert int(want.sum()) >= len(pick) > 0
    assert unsee_untrained(t.state) == int(want.sum())
    assert torch.equal(t.state.seen, seen & ~want)
    # without the residual: None, and nothing unmarked
    import dataclasses

    legacy = Trainer(tiny_scene, dataclasses.replace(tiny_config, avatar=dataclasses.replace(tiny_config.avatar, color_residual=False)))
    legacy.step()
    assert untrained_colours(legacy.model) is None and unsee_untrained(legacy.state) == 0


def test_the_finish_leaves_no_seen_gaussian_training_never_coloured(tiny_scene, tiny_config):
    t = _trained(tiny_scene, tiny_config)
    from reconstruct.train.seen_recount import untrained_colours

    with torch.no_grad():
        t.model.decoder.color_residual[torch.nonzero(t.state.seen).squeeze(1)[::5]] = 0.0
    note = t.plan.finish(t)
    assert "whose colour training never touched are unseen" in note
    # the fill sets the residuals of what it paints, so every row is touched now; the seen ones were before it
    assert not bool((t.state.seen & untrained_colours(t.model)).any())
    off = _trained(tiny_scene, tiny_config, seen_trained_only=False)
    with torch.no_grad():
        off.model.decoder.color_residual[torch.nonzero(off.state.seen).squeeze(1)[::5]] = 0.0
    assert "never touched" not in (off.plan.finish(off) or "")
