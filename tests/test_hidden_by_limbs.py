"""Gaussians hidden behind the arms in every training frame (``train/hidden_by_limbs.py``): the
blend weights it reads, which Gaussians it flags on the garment layer and on the torso (against
the arms' own rendered alpha), and Stage I's finish filling them."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from reconstruct.body.parts import PART_INDEX
from reconstruct.camera import Camera
from reconstruct.train.config import Stage1Config
from reconstruct.train.hidden_by_limbs import arm_gaussians, blend_weights, hidden_by_limbs
from reconstruct.train.render import render_avatar


@pytest.fixture
def layered(tiny_scene, tiny_config):
    """A Stage I trainer on the tiny scene with a skirt-like layer from the waist to above the knees
    (48 columns, rows every 2 cm: discs a few centimetres wide, as a hand covers them)."""
    from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, landmark_heights
    from tests.test_garment_layer_avatar import _trainer

    body = tiny_scene.body_model()
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)
    return _trainer(tiny_scene, tiny_config, build_garment_layer(body, hint, cols=48, row_step=0.02))


@pytest.fixture
def tight(tiny_scene, tiny_config):
    from reconstruct.train.trainer import Trainer

    return Trainer(tiny_scene, tiny_config, None)


def _fronts(t):
    """(N+M,) bool: the front half of the layer (by its built depth) and of the torso."""
    m = t.model
    N = m.num_body
    y = m.base_positions[:, 1]
    front = torch.zeros(m.num_gaussians, dtype=torch.bool)
    torso = torch.as_tensor(np.asarray(m.parts())[:N] == PART_INDEX["torso"])
    front[:N] = torso & (y[:N] < y[:N][torso].mean())
    if m.num_layer:
        front[N:] = y[N:] < y[N:].mean()
    return front


def _arm_in_front(t, depth: float, on: str, size: int = 160):
    """The trainer's frame-0 Gaussians with each arm laid flat over the middle of the front upper half
    of the layer (``on="layer"``) or of the torso (``on="torso"``) in the image, ``depth`` metres
    nearer a front camera (negative: behind it); that camera (``size`` px), the arm mask and a
    ``data`` stand-in holding the one frame."""
    m = t.model
    N = m.num_body
    i = t.data.frames[0]
    with torch.no_grad():
        if m.num_layer:
            m.layer_opacity.fill_(3.0)  # opaque cloth
        posed = t.state.posed(i)
    means = posed.means.detach().clone()
    front = _fronts(t)
    pick = front.clone()
    pick[N:] &= on == "layer"
    pick[:N] &= on == "torso"
    z = means[:, 2]
    pick &= z > z[pick].median()  # the upper half
    target = means[pick].mean(0)
    cam = Camera.orbit(0.0, 0.0, 2.0, target.double().numpy(), width=size, height=size, fov_y_deg=30.0)
    towards = torch.as_tensor(cam.center, dtype=means.dtype) - target
    towards = towards / towards.norm()
    arm = arm_gaussians(m)
    parts = np.asarray(m.parts())
    for side in "LR":  # each arm laid flat over the target (its depth along the view taken out)
        one = torch.as_tensor(np.isin(parts, [PART_INDEX[p + side] for p in ("upperarm.", "lowerarm.", "hand.")])) & arm
        rel = means[one] - means[one].mean(0)
        means[one] = target + depth * towards + rel - (rel @ towards)[:, None] * towards
    moved = dataclasses.replace(posed, means=means, opacities=torch.ones_like(posed.opacities).where(
        arm, posed.opacities))
    data = SimpleNamespace(frames=[i], targets={i: SimpleNamespace(camera=cam)}, background=torch.zeros(3))
    return moved, cam, arm, data


def test_blend_weights_sum_to_the_rendered_alpha(layered):
    """Each pixel's blend weights add up to its alpha, so the weights summed over the Gaussians are
    the rendered alpha summed over the image (an independent reading of the same render)."""
    posed, cam, _, _ = _arm_in_front(layered, 0.05, "layer")
    w = blend_weights(posed, cam, torch.zeros(3))
    with torch.no_grad():
        alpha = render_avatar(posed, cam, torch.zeros(3), normals=False).alpha
    assert w.shape == (posed.means.shape[0],) and w.dtype == torch.float64
    assert float(w.min()) >= 0
    assert float(w.sum()) == pytest.approx(float(alpha.double().sum()), rel=1e-4)


@pytest.mark.parametrize("on", ["layer", "torso"])
def test_what_is_behind_an_arm_is_flagged_where_the_arm_covers_it(layered, tight, monkeypatch, on):
    """With the arms 5 cm in front of the layer (or, on an avatar without one, of the torso), the
    Gaussians there whose footprint the arms alone cover (their rendered alpha above 0.95 within
    1.5 sigma of the centre, the arms' depth nearer there) are flagged, those of the front whose
    footprint the arms do not reach (alpha below 0.05 within 2 sigma) are not, and no arm Gaussian
    is. Moved 15 cm behind that front, they hide nothing nearer the camera than themselves."""
    t = layered if on == "layer" else tight
    N = t.model.num_body
    part = torch.zeros(t.model.num_gaussians, dtype=torch.bool)
    if on == "layer":
        part[N:] = True
    else:
        part[:N] = torch.as_tensor(np.asarray(t.model.parts())[:N] == PART_INDEX["torso"])
    front = (_fronts(t) & part).numpy()
    for depth, expect in ((0.05, True), (-0.15, False)):
        posed, cam, arm, data = _arm_in_front(t, depth, on)
        monkeypatch.setattr(t.state, "posed", lambda i, p=posed: p)
        hidden = hidden_by_limbs(t.state, data)
        assert hidden.shape == (t.model.num_gaussians,) and not hidden[arm].any()
        if not expect:  # behind the front: nothing nearer the camera than every arm Gaussian is hidden
            _, zs = cam.project(posed.means.detach().double().numpy())
            nearer = zs < zs[arm.numpy()].min() - 0.01
            assert nearer[front].sum() >= 5
            assert not hidden.numpy()[nearer].any()
            continue
        only_arm = dataclasses.replace(posed, opacities=posed.opacities * arm)
        with torch.no_grad():
            r = render_avatar(only_arm, cam, torch.zeros(3), normals=False)
        a = r.alpha.squeeze(-1).numpy()
        arm_depth = r.depth.squeeze(-1).numpy()  # their expected depth
        sel = np.flatnonzero(part.numpy())
        uv, z = cam.project(posed.means[sel].double().numpy())
        inside = (uv[:, 0] >= 3) & (uv[:, 0] < cam.width - 3) & (uv[:, 1] >= 3) & (uv[:, 1] < cam.height - 3) & (z > 0)
        c = np.clip(uv.round().astype(int), 0, [cam.width - 1, cam.height - 1])
        # each disc's footprint: 2 sigma of its widest axis, in pixels
        radius = np.ceil(2 * posed.scales[sel].detach().double().numpy().max(1) * cam.fx / np.maximum(z, 1e-6))

        def arm_alpha(k, r, reduce):
            r = int(r)
            return reduce(a[max(c[k, 1] - r, 0):c[k, 1] + r + 1, max(c[k, 0] - r, 0):c[k, 0] + r + 1])

        # covered: the arms' alpha above 0.95 over 1.5 sigma round its centre, and it lies behind
        # them there (a flared hem stands out in front of an arm laid over the waist)
        behind = z > arm_depth[c[:, 1], c[:, 0]] + 0.01
        covered = inside & front[sel] & behind & np.array([arm_alpha(k, 0.75 * radius[k], np.min) > 0.95
                                                          for k in range(len(c))])
        # clear: a front Gaussian whose whole footprint the arms leave (the back's are behind the
        # front and partly behind the arms through it)
        clear = inside & front[sel] & np.array([arm_alpha(k, radius[k], np.max) < 0.05 for k in range(len(c))])
        flags = hidden.numpy()[sel]
        assert covered.sum() >= 5 and clear.sum() >= 5, (covered.sum(), clear.sum())
        assert flags[covered].mean() > 0.9
        assert not flags[clear].any()


def test_bad_settings_are_clear_errors(layered):
    data = SimpleNamespace(frames=[0], targets={}, background=torch.zeros(3))
    with pytest.raises(ValueError, match="share"):
        hidden_by_limbs(layered.state, data, share=0.0)
    with pytest.raises(ValueError, match="min_weight"):
        hidden_by_limbs(layered.state, data, min_weight=0.0)


def test_no_frames_no_flags(tight):
    assert hidden_by_limbs(tight.state, SimpleNamespace(frames=[], targets={}, background=torch.zeros(3))) is None


@pytest.mark.parametrize("where", ["layer", "body"])
def test_the_finish_fills_the_hidden(layered, monkeypatch, where):
    """Stage I's finish makes the flagged Gaussians unseen and takes them out of the fill's ring
    (``ring_trained``) and says how many; the layer's also out of the trained opacities and handed
    to the fill as gaps. With the setting off (and for runs recorded before it) they stay as they
    were. Four seen Gaussians of the layer, or of the body's torso, are flagged."""
    from reconstruct.train import plan as plan_module

    t = layered
    for _ in range(2):
        t.step()
    N = t.model.num_body
    setting = "layer_hidden_by_limbs" if where == "layer" else "body_hidden_by_limbs"
    other = "body_hidden_by_limbs" if where == "layer" else "layer_hidden_by_limbs"
    flagged = torch.zeros(t.model.num_gaussians, dtype=torch.bool)
    monkeypatch.setattr(plan_module, "hidden_by_limbs", lambda state, data, **kw: flagged.clone())
    handed = {}
    real_fill, real_opacity = plan_module.fill_unseen_colors, plan_module.fill_unseen_layer_opacity

    def fill(state, **kw):
        handed["seen"] = state.seen.clone()
        handed["ring"] = kw.get("ring_trained")
        handed["gaps"] = kw.get("layer_gaps")
        return real_fill(state, **kw)

    def opacity(state, trained, **kw):
        handed["trained"] = trained.clone()
        return real_opacity(state, trained, **kw)

    monkeypatch.setattr(plan_module, "fill_unseen_colors", fill)
    monkeypatch.setattr(plan_module, "fill_unseen_layer_opacity", opacity)
    before = t.state.seen.clone()
    t.plan.settings = dataclasses.replace(t.plan.settings, **{setting: False, other: False})
    t.plan.finish(t)
    if where == "layer":
        pick = N + torch.nonzero(handed["seen"][N:]).squeeze(1)[:4]
    else:
        torso = torch.as_tensor(np.asarray(t.model.parts())[:N] == PART_INDEX["torso"])
        pick = torch.nonzero(handed["seen"][:N] & torso).squeeze(1)[:4]
    assert len(pick) == 4
    flagged[pick] = True
    assert bool(handed["seen"][flagged].all())  # off: seen
    t.state.seen.copy_(before)
    t.plan.settings = dataclasses.replace(t.plan.settings, **{setting: True})
    note = t.plan.finish(t)
    assert not bool(handed["seen"][flagged].any())
    assert handed["ring"] is not None and not bool(torch.as_tensor(handed["ring"])[flagged].any())
    if where == "layer":
        assert not bool(handed["trained"][flagged[N:]].any())
        assert torch.equal(torch.as_tensor(handed["gaps"]), flagged)  # their colours read round them
        assert "4 garment-layer Gaussians the arms and hands hid" in note
    else:
        assert handed["gaps"] is None
        assert "4 body Gaussians the arms and hands hid" in note
    assert getattr(Stage1Config.from_dict({}), setting) is False
    assert getattr(Stage1Config(), setting) is True
    assert getattr(Stage1Config.paper(), setting) is False


def test_the_fill_takes_a_gap_colour_only_near_the_rows(layered, monkeypatch):
    """``fill_unseen_colors`` with ``layer_gaps``: a gap cell whose colour read along its row or
    column (here given) lies within ``_GAP_TOLERANCE`` of the wrap fill's gets it; one further off
    (the shirt beside an open flap) keeps the wrap fill's; with no gaps given both keep it."""
    from reconstruct.train import unseen_fill

    t = layered
    for _ in range(2):
        t.step()
    N, M = t.model.num_body, t.model.num_layer
    seen = torch.zeros(N + M, dtype=torch.bool)
    seen[:N] = True
    seen[N:N + M // 2] = True  # the layer's first half seen, the rest unseen
    t.state.seen.copy_(seen)
    gaps = torch.zeros(N + M, dtype=torch.bool)
    near, far = N + M // 2 + 3, N + M // 2 + 7
    gaps[[near, far]] = True

    def colours_after(layer_gaps, offsets):
        saved = t.model.decoder.color_residual.detach().clone()
        base = {}
        real = unseen_fill.enclosed_gap_colors

        def given(neighbours, sources, colors, todo, reach):
            out = real(neighbours, sources, colors, todo, reach=reach)
            out[:] = np.nan
            for g, d in offsets.items():
                out[g - N] = base["row"][g] + d
            return out

        monkeypatch.setattr(unseen_fill, "enclosed_gap_colors", given)
        real_wrap = unseen_fill.wrap_fill_colors

        def wrap(*a, **kw):
            filled = real_wrap(*a, **kw)
            base["row"] = np.asarray(filled, np.float64)
            return filled

        monkeypatch.setattr(unseen_fill, "wrap_fill_colors", wrap)
        unseen_fill.fill_unseen_colors(t.state, layer_gaps=layer_gaps, layer_gap_reach=16)
        with torch.no_grad():
            c = t.model.canonical(None).colors.detach().double().numpy()
        t.model.decoder.color_residual.data.copy_(saved)
        return c, base["row"]

    offsets = {near: np.array([0.1, -0.1, 0.05]), far: np.array([0.4, 0.4, 0.4])}
    c, row = colours_after(gaps, offsets)
    np.testing.assert_allclose(c[near], np.clip(row[near] + offsets[near], 1e-3, 1 - 1e-3), atol=2e-3)
    np.testing.assert_allclose(c[far], np.clip(row[far], 1e-3, 1 - 1e-3), atol=2e-3)
    c0, row0 = colours_after(None, offsets)
    np.testing.assert_allclose(c0[near], np.clip(row0[near], 1e-3, 1 - 1e-3), atol=2e-3)
