"""The end-of-Stage-I recount's blend weights: a Gaussian the training images blended into the
person's pixels is seen (first hit or not), so the unseen fill does not repaint what the images
fitted; a garment-layer Gaussian the training rays reached keeps its trained opacity."""

import dataclasses

import numpy as np
import pytest
import torch
from scipy.ndimage import binary_erosion

from reconstruct.avatar.config import AvatarConfig
from reconstruct.train.config import Stage1Config
from reconstruct.train.render import render_avatar
from reconstruct.train.seen_recount import (BODY_AWAY_COS, INSET, MIN_PERSON_SHARE, PERSON, blended_on_person,
                                            keep_seen_on_person, person_coverage)
from reconstruct.train.trainer import Trainer

_SMALL = AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                      hidden=32)


def _trained(scene, steps=12, avatar=_SMALL, **kw):
    cfg = Stage1Config(iters=30, eval_every_seconds=1e9, checkpoint_every_seconds=1e9, crop_margin=4, avatar=avatar,
                       **kw)
    t = Trainer(scene, cfg)
    for _ in range(steps):
        t.step()
    return t


@pytest.fixture(scope="module")
def one_photo():
    """The tiny scene's person in a single frame: most of what draws it is no first hit."""
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    return build_synthetic_scene(SyntheticConfig(seed=1, num_frames=1, image_size=128, num_eval_azimuths=8,
                                                 eval_frames=1, texture_size=128), progress=False)


_PHOTO_AVATAR = dataclasses.replace(_SMALL, gaussian_resolution=96)
W_PHOTO = 0.25 * (128 / 512) ** 2  # the default's 0.25 px of a 512-px frame, in the 128-px frame's pixels


def _one_hot_sums(t, ids: list[int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Reference without autograd: each Gaussian of ``ids`` alone coloured 1 in one channel, on a
    black background; (frames, len(ids)): the image's sum over person pixels, over all pixels and
    over the person's pixels ``INSET`` px inside the silhouette (scipy's erosion)."""
    frames = list(t.data.frames)
    person, total, inner = (torch.zeros(len(frames), len(ids), dtype=torch.float64) for _ in range(3))
    for start in range(0, len(ids), 3):
        chunk = ids[start:start + 3]
        for f, i in enumerate(frames):
            tgt = t.data.targets[i]
            with torch.no_grad():
                posed = t.state.posed(i)
                colors = torch.zeros_like(posed.colors)
                for c, g in enumerate(chunk):
                    colors[g, c] = 1.0
                rgb = render_avatar(dataclasses.replace(posed, colors=colors), tgt.camera, torch.zeros(3),
                                    normals=False).rgb.double()
            m = (tgt.mask > PERSON).numpy()
            core = torch.as_tensor(binary_erosion(m, np.ones((2 * INSET + 1,) * 2), border_value=1)).double()
            for c in range(len(chunk)):
                person[f, start + c] = (rgb[..., c] * torch.as_tensor(m).double()).sum()
                total[f, start + c] = rgb[..., c].sum()
                inner[f, start + c] = (rgb[..., c] * core).sum()
    return person, total, inner


def _outside(t, ids: list[int]) -> torch.Tensor:
    """(frames, len(ids)) bool: the frame's camera sees the Gaussian's surface (its body or layer
    normal, posed; not the learned one) from outside, in float64. The rule applies it to the
    garment layer only."""
    outside = torch.zeros(len(t.data.frames), len(ids), dtype=torch.bool)
    m = t.model
    for f, i in enumerate(t.data.frames):
        with torch.no_grad():
            c = t.state.canonical(i)
            nrm = m.pose(dataclasses.replace(c, normals=m.base_normals), t.state.frame_transforms(i)).normals.double()
            v = torch.as_tensor(t.data.targets[i].camera.center, dtype=torch.float64) - t.state.posed(i).means.double()
        outside[f] = (v * nrm).sum(1)[ids] >= 0
    return outside


W = 0.02  # pixels of blend weight in the tiny scene's 64-px frames


def test_blend_weights_match_one_hot_renders(tiny_scene):
    t = _trained(tiny_scene)
    cov = person_coverage(t.state, t.data, weights=True)
    assert cov.weight.shape == cov.total.shape == (t.state.num_gaussians,)
    assert torch.all(cov.weight <= cov.total + 1e-6) and float(cov.weight.sum()) > 0
    order = torch.argsort(cov.weight, descending=True)
    gen = torch.Generator().manual_seed(0)
    some = torch.nonzero(cov.total > 1e-3).squeeze(1)
    ids = [int(g) for g in order[:6]] + [int(g) for g in some[torch.randperm(len(some), generator=gen)[:6]]]
    person, total, inner = _one_hot_sums(t, ids)
    assert len(t.data.frames) > 1
    close = lambda a, b: torch.allclose(a, b, rtol=1e-4, atol=1e-5)  # noqa: E731
    assert close(cov.weight[ids], person.sum(0)) and close(cov.total[ids], total.sum(0))
    # the rule's weight: one frame's, on the person's pixels INSET px inside the silhouette; the
    # body's count in every frame, also those whose camera its posed normal turns from
    assert t.model.layer is None
    outside = _outside(t, ids)
    assert close(cov.weight_max[ids], inner.max(0).values)
    assert close(cov.total_max[ids], total.max(0).values)
    assert bool((inner * ~outside).max() > 1e-3)  # some of it comes from frames it faces away from
    assert bool((inner.max(0).values < person.max(0).values - 1e-3).any())  # the band matters for some
    # the first hits are those of the recount without weights
    assert torch.equal(cov.first_hits, person_coverage(t.state, t.data).first_hits)


def test_blended_gaussians_become_seen_and_the_share_rule(one_photo):
    t = _trained(one_photo, avatar=_PHOTO_AVATAR)
    cov = person_coverage(t.state, t.data, weights=True)
    assert torch.all(cov.weight_max <= cov.weight + 1e-9)  # one frame, facing or not
    blended = blended_on_person(cov, W_PHOTO)
    # the point: Gaussians the image blended in with some weight that are no first hit
    assert int((blended & (cov.first_hits == 0)).sum()) > 0
    before = t.state.seen.clone()
    k = keep_seen_on_person(t.state, t.data, min_weight=W_PHOTO)
    on = ((cov.first_hits > 0) | blended) & ~cov.faces_away  # nothing whose surface faces away
    assert torch.equal(t.state.seen, before & on | on & ~before)
    assert k.dropped == int((before & ~on).sum()) and k.added == int((on & ~before).sum()) > 0
    # without weights: first hits only, nothing added
    t2 = _trained(one_photo, avatar=_PHOTO_AVATAR)
    seen2 = t2.state.seen.clone()
    assert keep_seen_on_person(t2.state, t2.data).added == 0
    assert torch.equal(t2.state.seen, seen2 & (cov.first_hits > 0) & ~cov.faces_away)
    # the share rule: with the person cut to the mask's left half, a Gaussian blended mostly into
    # the right half is not marked, however large its weight on the left
    for tgt in t.data.targets.values():
        tgt.mask[:, tgt.mask.shape[1] // 2:] = 0.0
    cut = person_coverage(t.state, t.data, weights=True)
    t.state.seen.zero_()
    keep_seen_on_person(t.state, t.data, min_weight=W_PHOTO, coverage=cut)
    added = t.state.seen & (cut.first_hits == 0)
    assert added.any()
    assert torch.all(cut.weight[added] >= MIN_PERSON_SHARE * cut.total[added] - 1e-9)
    mostly_right = (cut.weight_max >= W_PHOTO) & (cut.weight < MIN_PERSON_SHARE * cut.total) & (cut.first_hits == 0)
    assert mostly_right.any() and not (t.state.seen & mostly_right).any()
    with pytest.raises(ValueError, match="without weights"):
        blended_on_person(person_coverage(t.state, t.data), W_PHOTO)


def test_the_fill_keeps_what_one_photo_drew(one_photo):
    """The end of Stage I on a single frame: with first hits alone the fill repaints Gaussians
    that draw a quarter pixel inside the person (and the photo changes); with the blend weights it
    repaints none of them but those whose surface faces away from the camera, and the photo
    changes less."""
    change, repainted = {}, {}
    for w in (None, W_PHOTO):
        t = _trained(one_photo, steps=25, avatar=_PHOTO_AVATAR, seen_min_weight=w)
        i = t.data.frames[0]
        tgt = t.data.targets[i]

        def render():
            with torch.no_grad():
                return render_avatar(t.state.posed(i), tgt.camera, torch.zeros(3), normals=False).rgb

        cov = person_coverage(t.state, t.data, weights=True)
        drew = blended_on_person(cov, W_PHOTO) & ~cov.faces_away
        colors = t.model.canonical(None).colors.detach()
        a = render()
        note = t.plan.finish(t)
        b = render()
        changed = (t.model.canonical(None).colors.detach() - colors).abs().amax(1) > 1e-4
        assert changed.any()
        repainted[w] = int((changed & drew).sum())
        change[w] = float((a - b).abs().mean(-1)[tgt.mask > PERSON].mean())
        assert ("blended into the person" in note) == (w is not None)
    assert repainted[None] > 0 and repainted[W_PHOTO] == 0
    assert change[W_PHOTO] < change[None]


def test_layer_reached_is_weight_over_opacity(tiny_scene, tiny_config):
    """Against renders with one layer Gaussian made opaque: its blend weight then is what the rays
    bring to it (transmittance times footprint), which ``layer_reached`` reads as weight / opacity
    (the largest over the frames that see its surface from outside)."""
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
    reach = cov.total_max[N:] / 0.3
    ids = [int(g) for g in torch.argsort(reach, descending=True)[:4]]
    ref = []
    for g in ids:
        with torch.no_grad():
            saved = m.layer_opacity[g].clone()
            m.layer_opacity[g] = 40.0 / m.config.garment_opacity_gain
            _, total, _ = _one_hot_sums(t, [N + g])
            m.layer_opacity[g] = saved
        ref.append(float((total[:, 0] * _outside(t, [N + g])[:, 0]).max()))
    # opaque, the Gaussian's footprint saturates at alpha's clamp (0.99) near its centre
    assert torch.allclose(reach[ids], torch.tensor(ref, dtype=torch.float64), rtol=0.05)
    reached = layer_reached(t.state, cov.total_max, W)
    assert torch.equal(reached, reach >= W) and reached.any() and not reached.all()


def test_the_layer_counts_only_frames_that_see_it_from_outside(tiny_scene, tiny_config, monkeypatch):
    """A garment layer is an open sheet: a frame that sees its surface from inside adds nothing to
    its Gaussians' one-frame weights. The body is closed, and its Gaussians count in every frame.
    Turned inside out (the surface normals the rule reads flipped, the renders the same), the
    layer's one-frame weights come from the other frames and the body's stay as they were."""
    from test_garment_layer_avatar import _layer, _trainer

    t = _trainer(tiny_scene, tiny_config, _layer(tiny_scene.body_model()))
    for _ in range(3):
        t.step()
    m = t.model
    N = m.num_body
    with torch.no_grad():  # a see-through layer, so that the body blends in behind it too
        m.layer_opacity.copy_(torch.logit(torch.full_like(m.layer_opacity, 0.3)) / m.config.garment_opacity_gain)
    cov = person_coverage(t.state, t.data, weights=True)
    assert float(cov.weight_max[N:].max()) > 0.05 and float(cov.weight_max[:N].max()) > 0.05
    read = t.state.posed_with_surface_normals

    def inside_out(frame, *, surface=True):  # the same render; the surface normals the rule reads, flipped
        posed, normals = read(frame, surface=surface)
        return posed, None if normals is None else -normals

    monkeypatch.setattr(t.state, "posed_with_surface_normals", inside_out)
    flipped = person_coverage(t.state, t.data, weights=True)
    assert torch.allclose(flipped.weight, cov.weight) and torch.allclose(flipped.total, cov.total)
    for before, after in ((cov.weight_max, flipped.weight_max), (cov.total_max, flipped.total_max)):
        # inside out, the layer leaves out the frames it counted (the front seen from outside)
        assert bool(((before[N:] > 0.05) & (after[N:] < 1e-3)).any())
    assert torch.allclose(flipped.weight_max[:N], cov.weight_max[:N])
    assert torch.allclose(flipped.total_max[:N], cov.total_max[:N])


def test_body_gaussians_facing_away_from_every_camera_are_not_seen(one_photo, monkeypatch):
    """A body Gaussian whose surface faces away from the camera by more than 120 degrees in every
    frame is not seen, however much it blends in (the shoulders' backs behind a photo's hair):
    the flags against the cosines in float64, and with the surface normals flipped (the same
    renders) the front the photo saw is the side that faces away, and the recount unmarks it."""
    t = _trained(one_photo, avatar=_PHOTO_AVATAR)
    N = t.model.num_body
    i = t.data.frames[0]
    with torch.no_grad():
        posed, normals = t.state.posed_with_surface_normals(i)
    to_cam = t.data.targets[i].camera.center[None, :] - posed.means[:N].double().numpy()
    cos = (to_cam * normals[:N].double().numpy()).sum(1) / np.linalg.norm(to_cam, axis=1)
    cov = person_coverage(t.state, t.data, weights=True)
    assert np.array_equal(cov.faces_away[:N].numpy(), cos < BODY_AWAY_COS)
    assert 0 < int(cov.faces_away.sum()) < N // 2  # the back, not the front
    front = (cov.first_hits > 0) & (torch.as_tensor(cos) > 0.6)
    assert front.any() and not cov.faces_away[front].any()
    read = t.state.posed_with_surface_normals

    def inside_out(frame, *, surface=True):
        posed, normals = read(frame, surface=surface)
        return posed, None if normals is None else -normals

    monkeypatch.setattr(t.state, "posed_with_surface_normals", inside_out)
    t.state.seen[:] = True
    k = keep_seen_on_person(t.state, t.data, min_weight=W_PHOTO)
    assert not t.state.seen[front].any() and k.dropped > int(front.sum())
    assert not k.blended_only[front].any()


def test_setting_defaults_old_records_and_bad_values():
    assert Stage1Config().seen_min_weight == 0.25
    assert Stage1Config.paper().seen_min_weight is None
    rec = Stage1Config().to_dict()
    del rec["seen_min_weight"]
    assert Stage1Config.from_dict(rec).seen_min_weight is None
    with pytest.raises(ValueError, match="seen_min_weight"):
        Stage1Config(seen_min_weight=0.0)


def test_blended_only_gaussians_keep_their_colour_but_are_no_source(tiny_scene):
    """Paint the seen Gaussians of the torso's left half pure red and call them blended only: the
    fill keeps them red but copies red nowhere; as ordinary seen Gaussians the red spreads."""
    from reconstruct.body.parts import PART_INDEX
    from reconstruct.train.unseen_fill import fill_unseen_colors

    t = _trained(tiny_scene, fill_unseen=False)
    m = t.model
    torso = torch.as_tensor(m.parts() == PART_INDEX["torso"]).bool()
    special = t.state.seen & torso & (m.base_positions[:, 0] > 0)
    assert special.any() and (~t.state.seen & torso).any()
    saved = m.decoder.color_residual.detach().clone()
    red = torch.tensor([1.0, 0.0, 0.0])

    def paint_red():
        with torch.no_grad():
            m.decoder.color_residual.copy_(saved)
            logit = m.decode_raw(None, None)["color"].detach()
            want = torch.logit(red.clamp(1e-3, 1 - 1e-3)).expand(int(special.sum()), 3)
            m.decoder.color_residual[special] = (want - logit[special]) / m.config.color_residual_gain

    def reddish(colors):
        return (colors[:, 0] > 0.8) & (colors[:, 1] < 0.2) & (colors[:, 2] < 0.2)

    spread = {}
    for not_sources in (None, special):
        paint_red()
        assert reddish(m.canonical(None).colors.detach()[special]).all()
        filled = fill_unseen_colors(t.state, not_sources=not_sources)
        assert filled > 0
        colors = m.canonical(None).colors.detach()
        assert reddish(colors[special]).all()  # seen: never repainted
        spread[not_sources is None] = int(reddish(colors[~t.state.seen]).sum())
    assert spread[True] > 0 and spread[False] == 0
