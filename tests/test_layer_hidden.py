"""Garment-layer Gaussians hidden behind the arms in the training frames (``train/layer_hidden.py``):
the blend weights it reads, which Gaussians it flags (against the arm's own rendered alpha), and
Stage I's finish filling them like the cloth."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from reconstruct.avatar.layer_through import ARM_PARTS
from reconstruct.body.parts import PART_INDEX
from reconstruct.camera import Camera
from reconstruct.train.config import Stage1Config
from reconstruct.train.layer_hidden import blend_weights, layer_hidden_by_limbs
from reconstruct.train.render import render_avatar


@pytest.fixture
def layered(tiny_scene, tiny_config):
    from tests.test_garment_layer_avatar import _layer, _trainer

    return _trainer(tiny_scene, tiny_config, _layer(tiny_scene.body_model()))


def _arm_in_front(t, depth: float, size: int = 160):
    """The layered trainer's frame-0 Gaussians with both arms moved over the middle of the layer's
    front upper half in the image, ``depth`` metres nearer a front camera (negative: behind it),
    that camera (``size`` px), the arm mask and a ``data`` stand-in holding the one frame."""
    m = t.model
    N = m.num_body
    i = t.data.frames[0]
    with torch.no_grad():
        m.layer_opacity.fill_(3.0)  # opaque cloth
        posed = t.state.posed(i)
    means = posed.means.detach().clone()
    front = m.base_positions[N:, 1] < m.base_positions[N:, 1].mean()
    rows = m.layer_rc[:, 0]
    target = means[N:][front & (rows < rows.max() // 2)].mean(0)
    cam = Camera.orbit(0.0, 0.0, 2.0, target.double().numpy(), width=size, height=size, fov_y_deg=30.0)
    towards = torch.as_tensor(cam.center, dtype=means.dtype) - target
    towards = towards / towards.norm()
    arm = torch.as_tensor(np.isin(m.parts()[:N], [PART_INDEX[p] for p in ARM_PARTS]))
    arm = torch.cat([arm, torch.zeros(m.num_layer, dtype=torch.bool)])
    means[arm] += target + depth * towards - means[arm].mean(0)
    moved = dataclasses.replace(posed, means=means, opacities=torch.ones_like(posed.opacities).where(
        arm, posed.opacities))
    data = SimpleNamespace(frames=[i], targets={i: SimpleNamespace(camera=cam)}, background=torch.zeros(3))
    return moved, cam, arm, data


def test_blend_weights_sum_to_the_rendered_alpha(layered):
    """Each pixel's blend weights add up to its alpha, so the weights summed over the Gaussians are
    the rendered alpha summed over the image (an independent reading of the same render)."""
    posed, cam, _, _ = _arm_in_front(layered, 0.05)
    w = blend_weights(posed, cam, torch.zeros(3))
    with torch.no_grad():
        alpha = render_avatar(posed, cam, torch.zeros(3), normals=False).alpha
    assert w.shape == (posed.means.shape[0],) and w.dtype == torch.float64
    assert float(w.min()) >= 0
    assert float(w.sum()) == pytest.approx(float(alpha.double().sum()), rel=1e-4)


def test_the_layer_behind_an_arm_is_flagged_where_the_arm_covers_it(layered, monkeypatch):
    """With the arms 5 cm in front of the layer, the layer Gaussians whose centre the arms alone
    cover (their rendered alpha above 0.95 within 2 px) are flagged, those of the front whose
    footprint the arms do not reach (alpha below 0.05 within 2 sigma) are not, and no body Gaussian
    is. Moved 15 cm behind the
    layer's front, the arms hide nothing of the front."""
    t = layered
    N = t.model.num_body
    for depth, expect in ((0.05, True), (-0.15, False)):
        posed, cam, arm, data = _arm_in_front(t, depth)
        monkeypatch.setattr(t.state, "posed", lambda i, p=posed: p)
        hidden = layer_hidden_by_limbs(t.state, data)
        assert hidden.shape == (t.model.num_gaussians,) and not hidden[:N].any()
        front = (t.model.base_positions[N:, 1] < t.model.base_positions[N:, 1].mean()).numpy()
        if not expect:  # behind the front (its back half may be hidden behind them: it is)
            assert not hidden[N:][front].any()
            continue
        only_arm = dataclasses.replace(posed, opacities=posed.opacities * arm)
        with torch.no_grad():
            a = render_avatar(only_arm, cam, torch.zeros(3), normals=False).alpha.squeeze(-1).numpy()
        uv, z = cam.project(posed.means[N:].double().numpy())
        inside = (uv[:, 0] >= 3) & (uv[:, 0] < cam.width - 3) & (uv[:, 1] >= 3) & (uv[:, 1] < cam.height - 3) & (z > 0)

        c = np.clip(uv.round().astype(int), 0, [cam.width - 1, cam.height - 1])
        # each disc's footprint: 2 sigma of its widest axis, in pixels
        radius = np.ceil(2 * posed.scales[N:].detach().double().numpy().max(1) * cam.fx / np.maximum(z, 1e-6))

        def arm_alpha(k, r, reduce):
            r = int(r)
            return reduce(a[max(c[k, 1] - r, 0):c[k, 1] + r + 1, max(c[k, 0] - r, 0):c[k, 0] + r + 1])

        covered = inside & np.array([arm_alpha(k, 2, np.min) > 0.95 for k in range(len(c))])
        # clear: a front Gaussian whose whole footprint the arms leave (the back's discs are behind
        # the front and partly behind the arms through it)
        clear = inside & front & np.array([arm_alpha(k, radius[k], np.max) < 0.05 for k in range(len(c))])
        flags = hidden[N:].numpy()
        assert covered.sum() >= 5 and clear.sum() >= 5, (covered.sum(), clear.sum())
        assert flags[covered].mean() > 0.9
        assert not flags[clear].any()


def test_bad_settings_are_clear_errors(layered):
    data = SimpleNamespace(frames=[0], targets={}, background=torch.zeros(3))
    with pytest.raises(ValueError, match="share"):
        layer_hidden_by_limbs(layered.state, data, share=0.0)
    with pytest.raises(ValueError, match="min_weight"):
        layer_hidden_by_limbs(layered.state, data, min_weight=0.0)


def test_no_layer_no_flags(tiny_scene, tiny_config):
    from reconstruct.train.trainer import Trainer

    t = Trainer(tiny_scene, tiny_config, None)
    assert t.model.layer is None
    assert layer_hidden_by_limbs(t.state, t.data) is None


def test_the_finish_fills_the_hidden_like_the_cloth(layered, monkeypatch):
    """Stage I's finish makes the flagged layer Gaussians unseen, takes them out of the fill's ring
    (``ring_trained``) and of the trained opacities, and says how many; with the setting off (and
    for runs recorded before it) they stay as they were."""
    from reconstruct.train import plan as plan_module

    t = layered
    for _ in range(2):
        t.step()
    N = t.model.num_body
    flagged = torch.zeros(t.model.num_gaussians, dtype=torch.bool)
    monkeypatch.setattr(plan_module, "layer_hidden_by_limbs", lambda state, data, **kw: flagged.clone())
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
    t.plan.settings = dataclasses.replace(t.plan.settings, layer_hidden_by_limbs=False)
    t.plan.finish(t)
    pick = N + torch.nonzero(handed["seen"][N:]).squeeze(1)[:4]
    assert len(pick) == 4
    flagged[pick] = True
    t.state.seen.copy_(before)
    t.plan.settings = dataclasses.replace(t.plan.settings, layer_hidden_by_limbs=True)
    note = t.plan.finish(t)
    assert not bool(handed["seen"][flagged].any())
    assert handed["ring"] is not None and not bool(torch.as_tensor(handed["ring"])[flagged].any())
    assert not bool(handed["trained"][flagged[N:]].any())
    assert torch.equal(torch.as_tensor(handed["gaps"]), flagged)  # their colours read round them
    assert "4 garment-layer Gaussians the arms and hands hid" in note
    assert Stage1Config.from_dict({}).layer_hidden_by_limbs is False
    assert Stage1Config().layer_hidden_by_limbs is True
    assert Stage1Config.paper().layer_hidden_by_limbs is False


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
