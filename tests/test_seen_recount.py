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
