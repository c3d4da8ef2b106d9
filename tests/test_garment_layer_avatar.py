"""The garment layer wired into the avatar (issue 20; docs/loose_clothing.md, "How it is wired"):
the switch, N body + M layer Gaussians through decoding, posing, rendering, the layer's opacity and
losses, checkpoints, exports, edits, the fills and Stage II. Tiny sizes: the layer is built from a
hand-made VolumeHint (the synthetic loose scenes take minutes to build)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from reconstruct.avatar import AvatarConfig, AvatarModel
from reconstruct.avatar.garment_layer import (GARMENT_PART, GarmentLayer, VolumeHint, build_garment_layer,
                                              garment_layer_for, landmark_heights, neighbour_strain)
from reconstruct.camera import Camera
from reconstruct.train.render import render_avatar


def _config(**kw) -> AvatarConfig:
    # every layer Gaussian its own decoder node unless a test says otherwise (the per-Gaussian
    # checks below; the nodes are tested on their own)
    kw.setdefault("garment_decode_every", 1)
    return AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                        hidden=32, **kw)


def _layer(body) -> GarmentLayer:
    """A skirt-like layer from the waist to above the knees: 16 columns, rows every 6 cm."""
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)
    return build_garment_layer(body, hint, cols=16, row_step=0.06)


@pytest.fixture(scope="module")
def body(tiny_scene):
    return tiny_scene.body_model()


@pytest.fixture(scope="module")
def layer(body):
    return _layer(body)


def _front_camera(points: torch.Tensor, size: int = 64) -> Camera:
    target = points.detach().double().mean(0).numpy()
    return Camera.orbit(0.0, 0.0, 3.0, target, width=size, height=size, fov_y_deg=40.0)


def _trainer(scene, config, layer, run_dir=None):
    from reconstruct.train.trainer import Trainer

    return Trainer(scene, config, run_dir, garment_layer=layer)


# ----- the switch ---------------------------------------------------------------------------------

def test_switch_values_defaults_and_old_records():
    from reconstruct import config as config_layer
    from reconstruct.train.config import Stage1Config

    assert AvatarConfig().garment_layer == "auto"
    assert AvatarConfig.paper().garment_layer == "off" and Stage1Config.paper().avatar.garment_layer == "off"
    with pytest.raises(ValueError, match="garment_layer must be one of off, auto, on"):
        AvatarConfig(garment_layer="yes")
    sets = config_layer.parse_overrides(Stage1Config, ["avatar.garment_layer=auto"], "Stage I")
    assert config_layer.with_overrides(Stage1Config(), sets).avatar.garment_layer == "auto"
    # a run recorded before the layer existed loads as "off", whatever the default becomes
    old = Stage1Config().to_dict()
    del old["avatar"]["garment_layer"]
    assert Stage1Config.from_dict(old).avatar.garment_layer == "off"


def test_off_is_the_model_before_the_layer(body):
    """With "off": one Gaussian per texel, the parameters and state of before, and the decoded
    Gaussians exactly the decoder's output on [S, S, uv] interpolated to the texels (the formula of
    before, recomputed here). (Checked bit-identical against the previous commit's model and four
    Stage I steps when the layer was wired in.)"""
    cfg = _config(decode_resolution=24)  # decoded on a coarser grid, interpolated to the texels
    torch.manual_seed(0)
    m = AvatarModel(body, cfg)
    assert m.interpolated and m.layer is None and m.num_layer == 0
    assert m.num_gaussians == len(m.uv_map) == m.num_body
    assert {k for k, _ in m.named_parameters()} == {"features", "decoder.color_residual"} | {
        f"decoder.{k}" for k, _ in m.decoder.named_parameters() if k != "color_residual"}
    assert not any(k.startswith("layer") for k in m.state_dict())
    assert m.neighbours().shape == (m.num_gaussians, 4)
    with torch.no_grad():
        c = m.canonical()
        raw = m.decoder(m.decoder_input())
        raw = {k: (v[m.node_index] * m.node_weights[..., None]).sum(1) for k, v in raw.items()}
        colors = torch.sigmoid(raw["color"] + cfg.color_residual_gain * m.decoder.color_residual)
    assert c.opacities is None
    assert torch.equal(c.colors, colors)
    assert torch.equal(c.means, m.base_positions + cfg.offset_scale * raw["offset"])
    posed = m.splats(c)
    assert torch.equal(posed.opacities, torch.ones(m.num_gaussians))


def test_on_without_loose_clothing_is_an_error_and_auto_gives_none(tiny_scene, body):
    frames = tiny_scene.frames
    assert garment_layer_for(body, frames, "off") is None
    assert garment_layer_for(body, frames, "auto", "scene tiny") is None  # tight clothing: no hint
    with pytest.raises(ValueError, match="garment_layer=on: scene tiny: the masks .* show no loose clothing"):
        garment_layer_for(body, frames, "on", "scene tiny")


# ----- N + M Gaussians ----------------------------------------------------------------------------

def test_layer_gaussians_decode_pose_and_render(body, layer):
    from reconstruct.body.pose import BodyPose

    torch.manual_seed(0)
    plain = AvatarModel(body, _config())
    torch.manual_seed(0)
    # the bare LBS of the layer (its clearance from the body is tested in test_layer_clearance.py)
    m = AvatarModel(body, _config(garment_clearance=0.0), layer=layer)
    N, M = plain.num_gaussians, layer.num_gaussians
    assert m.num_body == N and m.num_layer == M and m.num_gaussians == N + M
    for name in ("base_positions", "base_normals", "skin_weights", "canonical_inverse", "texel_spacing",
                 "base_tangents", "texel_steps"):
        assert getattr(m, name).shape[0] == N + M, name
    assert m.decoder.color_residual.shape == (N + M, 3)
    assert tuple(m.layer_features.shape) == (1, 8, *layer.grid_shape)
    assert torch.equal(m.base_positions[N:], layer.positions)  # the layer's rows after the body's
    assert (m.parts()[N:] == GARMENT_PART).all() and (m.parts()[:N] == plain.parts()).all()
    # the layer's decoder inputs lie outside the body's uv square
    assert (m.layer_uv.abs().max(1).values > 1.0).all()
    with torch.no_grad():
        c, c0 = m.canonical(), plain.canonical()
    assert c.means.shape == (N + M, 3) and c.opacities.shape == (N + M,)
    # the body decodes as without the layer (same initial parameters; one decoder call for both)
    assert torch.allclose(c.colors[:N], c0.colors, atol=1e-6) and torch.allclose(c.means[:N], c0.means, atol=1e-6)
    assert torch.allclose(c.means[N:], layer.positions)  # offsets start at zero
    assert torch.all(c.opacities[:N] == 1) and torch.allclose(c.opacities[N:], torch.full((M,), 0.5))
    # any subset, in any order, decodes like the whole
    idx = torch.tensor([N + 3, 5, N, 7, N + M - 1, 2])
    with torch.no_grad():
        ci = m.canonical(index=idx)
    assert torch.allclose(ci.colors, c.colors[idx], atol=1e-6) and torch.allclose(ci.means, c.means[idx], atol=1e-6)
    assert torch.equal(ci.opacities, c.opacities[idx])
    # posing: the layer moves by its own (blended) weights, like GarmentLayer.posed
    rng = np.random.default_rng(0)
    pose = BodyPose(rng.normal(0, 0.15, (body.num_joints, 3)), np.array([0, 0, 0.3]), np.array([0.1, 0, 0]))
    T = body.bone_transforms(pose)
    with torch.no_grad():
        posed = m.pose(c, T.float())
    ref, _ = layer.posed(body, pose)
    assert (posed.means[N:].double() - ref).abs().max() < 1e-4
    assert torch.equal(posed.opacities, c.opacities)
    # every view keeps the whole layer (a see-through sheet), culls only the body's far side
    keep = m.facing(m.lbs_matrices(T.float()), np.array([0.0, -3.0, 0.0]))
    assert (keep >= N).sum() == M and len(keep) < N + M
    # rendering: the layer covers the gap between the thighs that the body alone leaves open
    cam = _front_camera(posed.means)
    bg = torch.zeros(3)
    with torch.no_grad():
        r = render_avatar(posed, cam, bg, normals=True)
        r0 = render_avatar(plain.pose(c0, T.float()), cam, bg, normals=True)
    assert r.rgb.shape == (64, 64, 3) and torch.isfinite(r.rgb).all()
    assert float(r.alpha.sum()) > float(r0.alpha.sum()) * 1.02


def test_grid_steps_against_numpy_on_two_tubes():
    """``garment_layer.grid_steps`` against an independent reference in float64: each tube's columns
    wrap round on themselves, rows by ``np.gradient`` (one-sided at the top and the hem)."""
    from reconstruct.avatar.garment_layer import grid_steps

    rng = np.random.default_rng(0)
    R, C, T = 5, 12, 2
    P = rng.normal(0, 0.1, (R, C, 3))
    got = grid_steps(torch.as_tensor(P.reshape(-1, 3)), (R, C), T).numpy().reshape(R, C, 2)
    for t in range(T):
        block = P[:, t * 6:(t + 1) * 6]
        side = np.linalg.norm(np.roll(block, -1, axis=1) - np.roll(block, 1, axis=1), axis=-1) / 2
        assert np.allclose(got[:, t * 6:(t + 1) * 6, 0], side, atol=1e-12)
    assert np.allclose(got[..., 1], np.linalg.norm(np.gradient(P, axis=0), axis=-1), atol=1e-12)


def test_layer_discs_grow_with_the_poses_stretch_of_the_grid(body, layer):
    """``layer_stretch_of``: 1 for a rigid pose; LBS matrices that stretch the layer 1.8 times in
    height and 1.3 times round its rings give those factors (the built grid's steps posed, over the
    canonical ones, over the slack; against float64 numpy), clamped to ``garment_max_stretch`` and
    never below 1.
    ``pose_with`` multiplies the layer discs' in-plane scales by them and leaves the body's and the
    discs' thickness alone; a subset needs them given, and then poses its rows alike; off, the
    canonical scales."""
    m = AvatarModel(body, _config(garment_clearance=0.0, garment_stretch_slack=1.0), layer=layer)
    N, M = m.num_body, m.num_layer
    with torch.no_grad():
        c = m.canonical()
    eye = torch.eye(4).expand(N + M, 4, 4).clone()
    turn = eye.clone()
    a = 0.7
    turn[:, :3, :3] = torch.tensor([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    turn[:, :3, 3] = torch.tensor([0.2, -0.1, 0.05])
    assert torch.allclose(m.layer_stretch_of(turn), torch.ones(M, 2), atol=1e-5)
    centre = m.base_positions[N:].mean(0)
    stretch = eye.clone()
    stretch[:, 0, 0] = stretch[:, 1, 1] = 1.3
    stretch[:, 2, 2] = 1.8
    stretch[:, :3, 3] = -torch.tensor([1.3, 1.3, 1.8]) * centre + centre
    got = m.layer_stretch_of(stretch)
    P = m.base_positions[N:].double().numpy()
    Q = (P - centre.double().numpy()) * [1.3, 1.3, 1.8] + centre.double().numpy()
    R, C = layer.grid_shape

    def steps(X):
        X = X.reshape(R, C, 3)
        side = np.linalg.norm(np.roll(X, -1, axis=1) - np.roll(X, 1, axis=1), axis=-1) / 2
        return np.stack([side, np.linalg.norm(np.gradient(X, axis=0), axis=-1)], -1).reshape(-1, 2)

    want = np.clip(steps(Q) / steps(P), 1.0, 3.0)
    assert np.allclose(got.double().numpy(), want, atol=1e-4)
    assert float(got[:, 1].min()) > 1.5 and float(got[:, 0].max()) < 1.4  # the flare tilts the columns
    slack = AvatarModel(body, _config(garment_clearance=0.0), layer=layer)  # the default slack, 1.3
    assert np.allclose(slack.layer_stretch_of(stretch).double().numpy(), np.clip(steps(Q) / steps(P) / 1.3, 1.0, 3.0),
                       atol=1e-4)
    squeeze = eye.clone()
    squeeze[:, 2, 2] = 0.5
    assert float(m.layer_stretch_of(squeeze)[:, 1].max()) == 1.0  # never shrunk
    big = eye.clone()
    big[:, 2, 2] = 5.0
    assert float(m.layer_stretch_of(big)[:, 1].max()) == pytest.approx(m.config.garment_max_stretch)
    with torch.no_grad():
        posed = m.pose_with(c, stretch)
        plain = m.pose_with(c, stretch, stretch=torch.ones(M, 2))
    assert torch.allclose(posed.scales[:N], c.scales[:N]) and torch.allclose(plain.scales, c.scales)
    assert torch.allclose(posed.scales[N:, :2], c.scales[N:, :2] * got, atol=1e-6)
    assert torch.allclose(posed.scales[N:, 2], c.scales[N:, 2])
    idx = torch.tensor([N + 5, 3, N + M - 1, N])
    with torch.no_grad():
        ci = m.canonical(index=idx)
        with pytest.raises(ValueError, match="stretch"):
            m.pose_with(ci, stretch[idx])
        sub = m.pose_with(ci, stretch[idx], stretch=got)
    assert torch.allclose(sub.scales, posed.scales[idx], atol=1e-6)
    off = AvatarModel(body, _config(garment_clearance=0.0, garment_stretch_scales=False), layer=layer)
    assert off.layer_stretch_of(stretch) is None
    with torch.no_grad():
        assert torch.allclose(off.pose_with(off.canonical(), stretch).scales, off.canonical().scales)
    with pytest.raises(ValueError, match="garment_max_stretch"):
        _config(garment_max_stretch=0.5)
    with pytest.raises(ValueError, match="garment_stretch_slack"):
        _config(garment_stretch_slack=0.9)


def test_layer_opacities_are_learnable(body, layer):
    m = AvatarModel(body, _config(), layer=layer)
    c = m.canonical()
    cam = _front_camera(c.means)
    r = render_avatar(m.splats(c), cam, torch.zeros(3), normals=False)
    (r.alpha.sum() + r.rgb.sum()).backward()  # (colours reach the features; at the start offsets and
    assert m.layer_opacity.grad is not None and float(m.layer_opacity.grad.abs().sum()) > 0
    assert m.layer_features.grad is not None and float(m.layer_features.grad.abs().sum()) > 0  # scales do not)
    groups = m.layer_param_groups(5e-4, 3e-3)
    assert [g["name"] for g in groups] == ["layer_features", "layer_opacity"]
    assert AvatarModel(body, _config()).layer_param_groups(5e-4, 3e-3) == []


def test_alpha_loss_fades_the_layer_where_the_mask_is_empty(body, layer):
    """The target mask is the body's own silhouette: the layer Gaussians that project outside it
    (between and beside the legs) lose their opacity under the alpha-vs-mask loss."""
    from reconstruct.train import losses as L

    torch.manual_seed(0)
    m = AvatarModel(body, _config(), layer=layer)
    N = m.num_body
    with torch.no_grad():
        c = m.canonical()
        body_only = m.splats(c)
        body_only.opacities = torch.cat([torch.ones(N), torch.zeros(m.num_layer)])
        cam = _front_camera(c.means)
        mask = (render_avatar(body_only, cam, torch.zeros(3), normals=False).alpha > 0.5).float()
        uv, z = cam.project(c.means[N:].double().numpy())
        px = np.clip(uv.astype(int), 0, 63)
        outside = torch.as_tensor(mask.numpy()[px[:, 1], px[:, 0]] == 0)
    assert outside.sum() >= 4
    start = float(torch.sigmoid(m.config.garment_opacity_gain * m.layer_opacity.detach())[outside].mean())
    opt = torch.optim.Adam([m.layer_opacity], lr=0.02)
    for _ in range(25):
        opt.zero_grad()
        with torch.no_grad():
            base = m.canonical()
        g = m.splats(base)
        g.opacities = m.opacities()
        L.mse(render_avatar(g, cam, torch.zeros(3), normals=False).alpha, mask).backward()
        opt.step()
    op = torch.sigmoid(m.config.garment_opacity_gain * m.layer_opacity.detach())
    assert start == pytest.approx(0.5)
    assert float(op[outside].mean()) < 0.25


def test_neighbour_regulariser_zero_at_rest_grows_when_stretched_and_has_the_right_gradient(body, layer):
    m = AvatarModel(body, _config(), layer=layer)
    with torch.no_grad():
        c = m.canonical()
    edges, rest = m.layer_edge_rows()
    assert len(edges) == len(layer.edges())
    assert float(neighbour_strain(c.means, edges, rest)) == 0.0
    N = m.num_body
    centre = c.means[N:].mean(0)
    stretched = c.means.clone()
    stretched[N:] = centre + 1.1 * (c.means[N:] - centre)
    s1 = float(neighbour_strain(stretched, edges, rest))
    stretched[N:] = centre + 1.3 * (c.means[N:] - centre)
    s3 = float(neighbour_strain(stretched, edges, rest))
    assert s1 == pytest.approx(0.01, rel=1e-3) and s3 == pytest.approx(0.09, rel=1e-3)
    # a subset: only the edges with both ends decoded, as rows of the subset
    idx = torch.arange(N - 3, N + 20)
    e_sub, r_sub = m.layer_edge_rows(idx)
    assert len(e_sub) > 0 and int(e_sub.max()) < len(idx)
    assert torch.equal(idx[e_sub], edges[(edges < N + 20).all(1)])
    # the gradient against finite differences (float64)
    g = torch.Generator().manual_seed(0)
    pts = (layer.positions[:40].double() + 0.003 * torch.randn(40, 3, generator=g, dtype=torch.float64))
    e = torch.as_tensor(layer.edges())
    e = e[(e < 40).all(1)]
    r = (layer.positions[e[:, 0]] - layer.positions[e[:, 1]]).norm(dim=1).double()
    assert torch.autograd.gradcheck(lambda x: neighbour_strain(x, e, r), (pts.requires_grad_(),))


# ----- training, checkpoints, exports -----------------------------------------------------------------

@pytest.fixture
def layered(tiny_scene, tiny_config, body):
    """A Stage I trainer on the tiny scene with a hand-made layer (the scene's clothing is tight)."""
    return _trainer(tiny_scene, tiny_config, _layer(body))


def test_stage1_steps_train_the_layer(layered):
    t = layered
    m = t.model
    assert {g["name"] for g in t.optimizer.param_groups} >= {"layer_features", "layer_opacity"}
    before = m.layer_opacity.detach().clone()
    for _ in range(3):
        out = t.step()
        assert not out.get("skipped")
        assert "alpha" in out and "layer_spacing" in out and out["alpha"] > 0
    assert not torch.equal(before, m.layer_opacity.detach())
    assert t.state.seen.shape == (m.num_gaussians,)
    snap = t.make_snapshot()
    assert len(snap.means) == m.num_gaussians


def test_auto_on_tight_clothing_trains_exactly_as_off(tiny_scene, tiny_config):
    """The default ``auto`` reads the masks, finds tight clothing and builds the model of ``off``:
    the same losses and parameters after two steps (no random numbers drawn by the hint)."""
    import dataclasses

    runs = {}
    for mode in ("off", "auto"):
        cfg = dataclasses.replace(tiny_config, avatar=dataclasses.replace(tiny_config.avatar, garment_layer=mode))
        t = _trainer(tiny_scene, cfg, "config")
        runs[mode] = (t, [t.step()["loss"] for _ in range(2)])
    assert runs["auto"][0].model.layer is None
    assert runs["auto"][1] == runs["off"][1]
    for a, b in zip(runs["auto"][0].model.parameters(), runs["off"][0].model.parameters()):
        assert torch.equal(a, b)


def test_a_body_without_the_leg_chain_gets_no_layer_with_auto_and_an_error_with_on(tiny_scene, body):
    """Dataset loaders bring SMPL bodies (other bone names): ``auto`` trains without a layer."""
    import types

    from reconstruct.avatar.garment_layer import missing_layer_bones

    assert missing_layer_bones(body) == []
    renamed = types.SimpleNamespace(bone_labels=[b.replace("upperleg01", "L_Hip") for b in body.bone_labels])
    assert missing_layer_bones(renamed) == ["upperleg01.L", "upperleg01.R"]
    assert garment_layer_for(renamed, tiny_scene.frames, "auto") is None
    with pytest.raises(ValueError, match="garment_layer=on: scene: its body model has no upperleg01.L"):
        garment_layer_for(renamed, tiny_scene.frames, "on")


def test_opacity_prior_is_the_mean_transparency_and_raises_hidden_opacities(tiny_scene, tiny_config, body):
    """``lambda_layer_opaque``: the term is mean(1 - opacity) over the layer's Gaussians, absent at
    0; with only it (every other weight 0) the layer's opacities go up."""
    import dataclasses

    from reconstruct.train.steps import GivenViewStep

    t = _trainer(tiny_scene, dataclasses.replace(tiny_config, lambda_layer_opaque=0.5), _layer(body))
    m = t.model
    outcome = GivenViewStep(t.config)(t)
    want = float((1 - m.opacities()[m.num_body:]).detach().mean())
    assert abs(float(outcome.terms["layer_opaque"].detach()) - want) < 1e-6
    assert outcome.weights["layer_opaque"] == 0.5
    assert abs(want - 0.5) < 1e-5  # the layer starts at opacity 0.5
    off = _trainer(tiny_scene, tiny_config, _layer(body))
    assert "layer_opaque" not in off.step()
    only = {f.name: 0.0 for f in dataclasses.fields(tiny_config) if f.name.startswith("lambda_")}
    t = _trainer(tiny_scene, dataclasses.replace(tiny_config, **{**only, "lambda_layer_opaque": 1.0}), _layer(body))
    before = t.model.opacities()[t.model.num_body:].detach().clone()
    for _ in range(3):
        t.step()
    after = t.model.opacities()[t.model.num_body:].detach()
    assert bool((after > before).all()), (before.mean(), after.mean())


def test_layer_step_sets_rows_and_columns(tiny_scene, tiny_config, body, monkeypatch):
    """``AvatarConfig.garment_layer_step``: metres between the layer's rows, the columns spaced alike
    (64 at 2 cm, 92 at 1.4 cm, 128 at 1 cm), even, at least 16; out-of-range steps are a clear error;
    a run recorded before the setting used 2 cm. The trainer builds the layer at the config's step
    and one-tube filter (``garment_filter_one_tube``)."""
    import dataclasses

    from reconstruct.avatar.garment_layer import layer_columns
    from reconstruct.train.config import Stage1Config

    assert AvatarConfig().garment_layer_step == 0.010
    assert layer_columns(0.02) == 64 and layer_columns(0.014) == 92 and layer_columns(0.010) == 128
    assert layer_columns(0.1) == 16
    old = Stage1Config().to_dict()
    del old["avatar"]["garment_layer_step"]
    assert Stage1Config.from_dict(old).avatar.garment_layer_step == 0.02
    assert all(layer_columns(s) % 2 == 0 for s in np.linspace(0.005, 0.1, 40))
    for bad in (0.001, 0.5):
        with pytest.raises(ValueError, match="garment_layer_step must be in"):
            AvatarConfig(garment_layer_step=bad)
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)
    a, b = (build_garment_layer(body, hint, cols=layer_columns(s), row_step=s) for s in (0.04, 0.02))
    band = 6  # the hem rows every 5 mm over 3 cm, in both
    assert b.grid_shape[1] == 2 * a.grid_shape[1] and b.grid_shape[0] - band > 1.8 * (a.grid_shape[0] - band)
    # the trainer builds the layer at the config's step (the tiny scene is tight: "on" needs a hint,
    # so the check goes through garment_layer_for's arguments)
    seen = {}
    monkeypatch.setattr("reconstruct.train.trainer.garment_layer_for", lambda *a, **k: seen.update(k) or None)
    cfg = dataclasses.replace(tiny_config, avatar=dataclasses.replace(tiny_config.avatar, garment_layer="auto",
                                                                      garment_layer_step=0.03,
                                                                      garment_filter_one_tube=1.7))
    _trainer(tiny_scene, cfg, "config")
    assert seen == {"row_step": 0.03, "one_tube_filter": 1.7}


def test_one_tube_filter_widens_a_one_tube_layers_blend_only(body):
    """``AvatarConfig.garment_filter_one_tube``: a one-tube layer's (a skirt's) skinning weights are
    filtered that many times wider than ``weight_diffusion``'s, so that they change less from
    column to column and from row to row; a two-tube layer (trousers) is the same whatever it is.
    Out-of-range values are a clear error; a run recorded before the setting used 1 (that the
    trainer passes the config's value: ``test_layer_step_sets_rows_and_columns``)."""
    import dataclasses

    from reconstruct.train.config import Stage1Config

    m = landmark_heights(body)
    one = VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)
    two = dataclasses.replace(one, two_legs=True)

    def roughness(layer):  # mean change of the weights to the next column and to the next row
        R, C = layer.grid_shape
        w = layer.weights.double().reshape(R, C, -1)
        return float((w - w.roll(1, 1)).abs().sum(-1).mean() + (w[1:] - w[:-1]).abs().sum(-1).mean())

    narrow, wide = (build_garment_layer(body, one, cols=32, row_step=0.04, one_tube_filter=f) for f in (1.0, 2.0))
    assert torch.allclose(wide.weights.sum(1), torch.ones(len(wide.weights), dtype=wide.weights.dtype), atol=1e-5)
    assert roughness(wide) < 0.9 * roughness(narrow), (roughness(wide), roughness(narrow))  # 0.78 measured
    assert torch.equal(narrow.positions, wide.positions)  # the filter moves no Gaussian
    a, b = (build_garment_layer(body, two, cols=32, row_step=0.04, one_tube_filter=f) for f in (1.0, 2.0))
    assert torch.equal(a.weights, b.weights)
    for bad in (0.1, 5.0):
        with pytest.raises(ValueError, match="garment_filter_one_tube must be in"):
            AvatarConfig(garment_filter_one_tube=bad)
    old = Stage1Config().to_dict()
    del old["avatar"]["garment_filter_one_tube"]
    assert Stage1Config.from_dict(old).avatar.garment_filter_one_tube == 1.0


def test_tight_runs_have_no_layer_terms(tiny_scene, tiny_config):
    import dataclasses

    t = _trainer(tiny_scene, tiny_config, "config")  # the config says "off"
    assert t.model.layer is None
    out = t.step()
    assert "alpha" not in out and "layer_spacing" not in out
    # the trainer asks the masks: the tiny scene's clothing is tight
    with_avatar = lambda mode: dataclasses.replace(  # noqa: E731
        tiny_config, avatar=dataclasses.replace(tiny_config.avatar, garment_layer=mode))
    assert _trainer(tiny_scene, with_avatar("auto"), "config").model.layer is None
    with pytest.raises(ValueError, match="garment_layer=on: scene .* show no loose clothing"):
        _trainer(tiny_scene, with_avatar("on"), "config")


def test_checkpoint_round_trip_rebuilds_the_layer(layered, tiny_scene, tiny_config, tmp_path):
    from reconstruct.train.checkpoint import garment_layer_of, load_checkpoint

    t = layered
    for _ in range(2):
        t.step()
    path = t.save(tmp_path / "checkpoint.pt")
    state = load_checkpoint(path)  # read as data (weights_only)
    saved = state["avatar"]["garment_layer"]
    assert isinstance(saved["grid_shape"], list) and isinstance(saved["hint"]["hem_z"], float)
    layer = garment_layer_of(state, str(path), t.state.body.num_joints)
    assert layer.same_as(t.model.layer) and layer.hint == t.model.layer.hint
    with torch.no_grad():
        want = t.state.canonical(None)
    # a trainer built without the layer ("off") takes the checkpoint's before loading it
    t2 = _trainer(tiny_scene, tiny_config, "config")
    assert t2.model.layer is None
    t2.load_state_dict(state, str(path))
    assert t2.model.layer is not None and t2.model.num_gaussians == t.model.num_gaussians
    # ... and one built with it directly (what RunFolder.resume does)
    t3 = _trainer(tiny_scene, tiny_config, layer)
    t3.load_state_dict(state, str(path))
    for tt in (t2, t3):
        with torch.no_grad():
            got = tt.state.canonical(None)
        for k in ("means", "normals", "colors", "scales", "opacities"):
            assert torch.equal(getattr(got, k), getattr(want, k)), k
        assert torch.equal(tt.state.seen, t.state.seen)
        out = tt.step()  # the optimiser state fits the rebuilt model
        assert not out.get("skipped")


def test_a_run_folder_resumes_with_its_layer(tiny_scene, tiny_config, body, tmp_path):
    from reconstruct.run_folder import RunFolder

    run = tmp_path / "run"
    run.mkdir()
    t = _trainer(tiny_scene, tiny_config, _layer(body), run)  # the config says "off": the layer was given
    t.step()
    t.save()
    with torch.no_grad():
        want = t.state.canonical(None)
    resumed = RunFolder(run).resume(tiny_scene)
    assert resumed.model.layer is not None and resumed.model.layer.same_as(t.model.layer)
    with torch.no_grad():
        got = resumed.state.canonical(None)
    assert torch.equal(got.colors, want.colors) and torch.equal(got.opacities, want.opacities)


def test_old_checkpoint_without_a_layer_loads_unchanged(tiny_scene, tiny_config, tmp_path, body):
    from reconstruct.train.checkpoint import garment_layer_of, load_checkpoint

    t = _trainer(tiny_scene, tiny_config, "config")
    t.step()
    path = t.save(tmp_path / "checkpoint.pt")
    state = load_checkpoint(path)
    assert "garment_layer" not in state["avatar"] and garment_layer_of(state) is None
    with torch.no_grad():
        want = t.state.canonical(None)
    # even into a trainer that was given a layer: the checkpoint's avatar has none
    t2 = _trainer(tiny_scene, tiny_config, _layer(body))
    t2.load_state_dict(state, str(path))
    assert t2.model.layer is None
    with torch.no_grad():
        got = t2.state.canonical(None)
    assert torch.equal(got.means, want.means) and torch.equal(got.colors, want.colors) and got.opacities is None


def test_malformed_layer_in_a_checkpoint_is_a_clear_error(layered):
    from reconstruct.train.checkpoint import CheckpointError, garment_layer_of

    state = layered.state_dict()
    state["avatar"]["garment_layer"]["positions"] = torch.zeros(3, 3)
    with pytest.raises(CheckpointError, match=r"run/checkpoint.pt: garment layer: positions must be a float tensor"):
        garment_layer_of(state, "run/checkpoint.pt")
    state["avatar"]["garment_layer"] = {"grid_shape": [2, 2]}
    with pytest.raises(CheckpointError, match="garment layer: missing entries"):
        garment_layer_of(state, "run/checkpoint.pt")


def test_ply_export_carries_the_layer_and_its_opacities(layered, tmp_path):
    from reconstruct.ply import read_gaussians_ply, write_snapshot_ply

    t = layered
    with torch.no_grad():
        t.model.layer_opacity.data[::2] = -0.1  # sigmoid(10 * -0.1) = 0.27
    snap = t.make_snapshot("canonical")
    path = write_snapshot_ply(tmp_path / "avatar.ply", snap)
    g = read_gaussians_ply(path)
    N, M = t.model.num_body, t.model.num_layer
    assert len(g.means) == N + M
    op = np.asarray(snap.opacities)
    assert np.all(op[:N] == 1.0) and np.all(op[N:] < 0.99)
    assert np.allclose(op[N::2], 1 / (1 + np.exp(1.0)), atol=1e-5)
    assert np.allclose(np.asarray(g.opacities), op, atol=1e-4)


# ----- per-Gaussian users: edits, fills, Stage II ---------------------------------------------------

def test_edits_take_the_layer(layered):
    from reconstruct.edits import Erase, Lock
    from reconstruct.edits.selection import part_mask
    from reconstruct.edits.session import EditSession

    t = layered
    m = t.model
    N, M = m.num_body, m.num_layer
    session = EditSession(t.state, autosave=False)
    sel = session.select_part("garment")
    assert sel.shape == (N + M,) and sel.sum() == M and sel[N:].all()
    assert not part_mask(m.parts(), "thigh.*")[N:].any()
    # grow over the layer's grid: one Gaussian of the layer grows into a plus shape (wrapping round)
    one = np.zeros(N + M, bool)
    one[N] = True
    session.select(one)
    grown = session.grow(1)
    cols = m.layer.grid_shape[1]
    assert set(np.flatnonzero(grown)) == {N, N + 1, N + cols - 1, N + cols}
    # erase the layer: gone from renders (opacity 0) and from snapshots
    session.select_part("garment")
    session.apply(Erase())
    assert len(t.make_snapshot().means) == N
    session.undo()
    assert len(t.make_snapshot().means) == N + M
    # a lock keeps the layer's opacities as they were
    session.apply(Lock())
    with torch.no_grad():
        before = t.state.canonical(None).opacities.clone()
        m.layer_opacity.data -= 0.2
        after = t.state.canonical(None).opacities
    assert torch.equal(before, after)


def test_unseen_fill_covers_the_layer(layered):
    from reconstruct.train.unseen_fill import fill_unseen_colors

    t = layered
    for _ in range(4):
        t.step()
    state = t.state
    N = t.model.num_body
    # the front half of the layer seen, the back half not
    front = t.model.base_normals[N:, 1] < 0
    state.seen[N:] = front
    assert state.seen[:N].any()
    n = fill_unseen_colors(state)
    assert n > 0
    assert torch.isfinite(t.model.decoder.color_residual).all()


def test_untrained_layer_gaussians_take_the_trained_cloths_opacity_at_their_height(layered):
    """The layer Gaussians no training camera faced get the median opacity of the row's trained
    ones (eroded); rows without any take the nearest row's; trained ones (opaque or made
    transparent), painted-seen ones and the body stay as they were."""
    from reconstruct.appearance.propagation import erode
    from reconstruct.train.unseen_fill import fill_unseen_layer_opacity

    t = layered
    m, state = t.model, t.state
    N = m.num_body
    R, C = m.layer.grid_shape
    rows = m.layer_rc[:, 0]
    cols = m.layer_rc[:, 1]
    saved_seen, saved_op = state.seen.clone(), m.layer_opacity.detach().clone()
    try:
        g = m.config.garment_opacity_gain
        with torch.no_grad():  # opacity varies along each row and down the rows
            m.layer_opacity.copy_(torch.logit(0.2 + 0.6 * (cols.float() / C) * (rows.float() + 1) / R) / g)
        trained = (cols < C // 2) & (rows < R - 1)  # half the columns faced a camera; the last row none
        state.seen[:] = False  # the seen flags do not decide: a transparent trained Gaussian is unseen
        before = m.opacities().detach().clone()
        n = fill_unseen_layer_opacity(state, trained, erosion=1)
        assert n == int((~trained).sum())
        after = m.opacities().detach()
        assert torch.equal(after[:N], before[:N]) and torch.allclose(after[N:][trained], before[N:][trained])
        full = torch.ones(m.num_gaussians, dtype=torch.bool)
        full[N:] = trained
        sources = torch.as_tensor(erode(full.numpy(), m.neighbours(), 1))[N:]
        have = [r for r in range(R) if bool(((rows == r) & sources).any())]
        assert R - 1 not in have and len(have) >= R // 2
        for r in range(R):
            src = min(have, key=lambda h: (abs(h - r), h))  # the last rows: the nearest one with any
            want = before[N:][(rows == src) & sources].median()
            got = after[N:][(rows == r) & ~trained]
            assert torch.allclose(got, torch.full_like(got, float(want)), atol=1e-5), r
        assert fill_unseen_layer_opacity(state, torch.ones(m.num_layer, dtype=torch.bool)) == 0
        state.seen[N:] = True  # painted or counted seen: left alone
        assert fill_unseen_layer_opacity(state, trained) == 0
        with pytest.raises(ValueError, match="trained flags must have shape"):
            fill_unseen_layer_opacity(state, trained[:-1])
    finally:
        state.seen.copy_(saved_seen)
        with torch.no_grad():
            m.layer_opacity.copy_(saved_op)



def test_finish_keeps_the_ring_of_decoded_colours_only_where_training_shaped_the_layer(layered, monkeypatch):
    """Stage I's finish hands the fill the Gaussians whose decoded colours training shaped: every
    body Gaussian (the ring round the seen body keeps its colours as before) and the layer's
    Gaussians that faced a training camera or that a training ray reached from outside (read before
    the untrained ones take the cloth's opacity). The inside of an open jacket's flap, seen from
    within at its edge, has no outer colour of its own: it showed as light specks from behind."""
    from reconstruct.train import plan as plan_module
    from reconstruct.train.unseen_fill import layer_faced_training, layer_reached
    from reconstruct.train.seen_recount import person_coverage

    import dataclasses

    t = layered
    for _ in range(3):
        t.step()
    # what the arms hid leaves the ring too (tests/test_hidden_by_limbs.py): not read here
    t.plan.settings = dataclasses.replace(t.plan.settings, layer_hidden_by_limbs=False, body_hidden_by_limbs=False)
    s = t.plan.settings
    calls = []
    real = plan_module.fill_unseen_colors
    monkeypatch.setattr(plan_module, "fill_unseen_colors", lambda state, **kw: calls.append(kw) or real(state, **kw))
    N = t.model.num_body
    faced = layer_faced_training(t.state, t.data)
    cov = person_coverage(t.state, t.data, hit_threshold=s.hit_threshold, weights=True)
    shaped = faced | layer_reached(t.state, cov.total_max, plan_module._RING_MIN_REACH)
    t.plan.finish(t)
    ring = calls[0]["ring_trained"]
    assert ring.dtype == torch.bool and ring.shape == (t.model.num_gaussians,)
    assert bool(ring[:N].all())
    assert torch.equal(ring[N:], shaped)
    assert 0 < int(shaped.sum()) < t.model.num_layer, "the hand-made layer must be partly untrained"


def test_untrained_layer_opacity_has_no_ring_below_the_hem(layered):
    """Below the hem the untrained Gaussians' opacities never rise again down the rows:
    a trained row below the hem whose median is higher than the row above (the hem's columns mixed)
    gives the untrained ones the row above's value; rows above the most opaque one keep theirs, and
    rows whose trained cloth is nearly emptied (median below 0.1) are empty."""
    from reconstruct.train.unseen_fill import fill_unseen_layer_opacity

    t = layered
    m, state = t.model, t.state
    N = m.num_body
    R, C = m.layer.grid_shape
    assert R >= 6
    rows = m.layer_rc[:, 0]
    cols = m.layer_rc[:, 1]
    saved_seen, saved_op = state.seen.clone(), m.layer_opacity.detach().clone()
    hem = R // 2
    profile = torch.full((R,), 0.9)
    profile[0] = 0.5  # the top fades into the body: kept
    profile[2] = 0.99  # the most opaque row; the rows under it, down to the hem, keep their 0.9
    profile[hem:] = 0.05  # emptied cloth below the hem: 0 (the margin)
    profile[hem + 1] = 0.4  # a stray row below the hem
    try:
        g = m.config.garment_opacity_gain
        with torch.no_grad():
            m.layer_opacity.copy_(torch.logit(profile[rows]) / g)
        trained = cols < C // 2
        state.seen[:] = False
        before = m.opacities().detach().clone()
        fill_unseen_layer_opacity(state, trained, erosion=0)
        got = m.opacities().detach()[N:]
        per_row = torch.stack([got[(rows == r) & ~trained].mean() for r in range(R)])
        want = profile.clone()
        want[hem:] = 1e-3
        assert torch.allclose(per_row, want, atol=1e-4), (per_row, want)
        # without the rule the stray row would have been copied: the case is real
        assert abs(float(before[N:][(rows == hem + 1) & trained].median()) - 0.4) < 1e-4
    finally:
        state.seen.copy_(saved_seen)
        with torch.no_grad():
            m.layer_opacity.copy_(saved_op)

def _filled_row_opacities(t, profile: torch.Tensor) -> torch.Tensor:
    """The layer's opacities set to ``profile`` (R,) by row, the left half of its columns trained,
    nothing seen, then ``fill_unseen_layer_opacity``: (R,) the mean opacity of each row's untrained
    Gaussians. The caller restores the model and the seen flags."""
    from reconstruct.train.unseen_fill import fill_unseen_layer_opacity

    m = t.model
    R, C = m.layer.grid_shape
    rows, cols = m.layer_rc[:, 0], m.layer_rc[:, 1]
    with torch.no_grad():
        m.layer_opacity.copy_(torch.logit(profile[rows]) / m.config.garment_opacity_gain)
    trained = cols < C // 2
    t.state.seen[:] = False
    fill_unseen_layer_opacity(t.state, trained, erosion=0)
    got = m.opacities().detach()[m.num_body:]
    return torch.stack([got[(rows == r) & ~trained].mean() for r in range(R)])


def test_a_low_row_above_the_hem_is_cloth_behind_a_hand(layered):
    """A row below one half between opaque rows (its front under a hand) is not the hem: the
    untrained Gaussians there take the lower of the most opaque rows above and below it, and the
    rows under it keep theirs down to the real hem (whose rows 3 cm down are all below one half)."""
    t = layered
    m, state = t.model, t.state
    R = m.layer.grid_shape[0]
    hem = R // 2
    dip = (2 + hem) // 2
    assert 2 < dip < hem
    saved_seen, saved_op = state.seen.clone(), m.layer_opacity.detach().clone()
    profile = torch.full((R,), 0.9)
    profile[2] = 0.99
    profile[dip] = 0.3
    profile[hem:] = 0.05
    try:
        per_row = _filled_row_opacities(t, profile)
        want = profile.clone()
        want[dip] = 0.9  # min(0.99 above, 0.9 below)
        want[hem:] = 1e-3
        assert torch.allclose(per_row, want, atol=1e-4), (per_row, want)
    finally:
        state.seen.copy_(saved_seen)
        with torch.no_grad():
            m.layer_opacity.copy_(saved_op)


def test_a_low_band_above_opaque_cloth_is_not_the_hem(layered):
    """Two low rows whose rows 3 cm down are low too (a hand and a clutch at a tilted photo's
    waist), but with 6 cm of opaque rows under them: not the hem. They take the lower of the most
    opaque rows above and below, the opaque rows keep theirs, and the real hem below empties the
    rest. With the band's rows taken for the hem, the whole back under them was emptied."""
    t = layered
    m, state = t.model, t.state
    R = m.layer.grid_shape[0]
    assert R >= 7, R
    zs = m.layer.positions.reshape(R, -1, 3)[:, :, 2].double().mean(1)
    assert 0.05 <= float(zs[4] - zs[5]) + 1e-9 and float(zs[2] - zs[3]) > 0.03  # rows 6 cm apart
    saved_seen, saved_op = state.seen.clone(), m.layer_opacity.detach().clone()
    profile = torch.full((R,), 0.05)
    profile[0], profile[1] = 0.9, 0.99
    profile[2:4] = 0.2  # the low band
    profile[4:6] = torch.tensor([0.9, 0.95])  # 6 cm of opaque cloth under it
    try:
        per_row = _filled_row_opacities(t, profile)
        want = profile.clone()
        want[2:4] = 0.95  # min(0.99 above, 0.95 below)
        want[6:] = 1e-3
        assert torch.allclose(per_row, want, atol=1e-4), (per_row, want)
        # one opaque row under the band is not cloth enough: the band is the hem, as before
        profile[5] = 0.05
        per_row = _filled_row_opacities(t, profile)
        want = torch.full((R,), 1e-3)
        want[0], want[1], want[2:5] = 0.9, 0.99, 0.2
        assert torch.allclose(per_row, want, atol=1e-4), (per_row, want)
    finally:
        state.seen.copy_(saved_seen)
        with torch.no_grad():
            m.layer_opacity.copy_(saved_op)


def test_the_model_finds_the_legs_under_its_layers_hem(layered):
    """``model_layer_shows_body`` on the model's own Gaussians: skin-coloured legs, grey cloth whose
    seen bottom row shows the legs' colour; only that row is flagged, and no body Gaussian."""
    from reconstruct.avatar.layer_through import model_layer_shows_body
    from reconstruct.body.parts import PART_INDEX

    m = layered.model
    N, M = m.num_body, m.num_layer
    R, C = m.layer.grid_shape
    rows = m.layer_rc[:, 0].numpy()
    skin, grey = np.array([0.66, 0.5, 0.45]), np.array([0.45, 0.45, 0.47])
    parts = m.parts()
    colours = np.tile(grey, (N + M, 1))
    legs = np.isin(parts[:N], [PART_INDEX[p] for p in ("thigh.L", "thigh.R", "shin.L", "shin.R")])
    colours[:N][legs] = skin
    front = m.base_positions[N:, 1].numpy() < m.base_positions[N:, 1].numpy().mean()
    colours[N:][front & (rows == R - 1)] = skin
    seen = np.ones(N + M, bool)
    seen[N:] = front
    flags = model_layer_shows_body(m, torch.as_tensor(seen), torch.as_tensor(colours))
    assert flags.shape == (N + M,) and not flags[:N].any()
    hem = front & (rows == R - 1)
    assert flags[N:][hem].mean() > 0.9, flags[N:][hem]
    assert not flags[N:][~hem].any()


def _arm_over_the_layer(t):
    """The layered trainer's model with grey colours and sleeve-coloured arms, frame 0's camera and
    posed means (a copy), the middle of the layer's front upper third there and the unit direction
    from it to the camera."""
    from reconstruct.avatar.layer_through import ARM_PARTS
    from reconstruct.body.parts import PART_INDEX

    m = t.model
    N, M = m.num_body, m.num_layer
    sleeve, grey = np.array([0.70, 0.74, 0.83]), np.array([0.30, 0.30, 0.32])
    arm = np.isin(m.parts()[:N], [PART_INDEX[p] for p in ARM_PARTS])
    colours = np.tile(grey, (N + M, 1))
    colours[:N][arm] = sleeve
    front = m.base_positions[N:, 1].numpy() < m.base_positions[N:, 1].numpy().mean()
    i = t.data.frames[0]
    cam = t.data.targets[i].camera
    with torch.no_grad():
        means = t.state.posed(i).means.double().numpy().copy()
    rows = m.layer_rc[:, 0].numpy()
    target = means[N:][front & (rows < rows.max() // 3)].mean(0)
    towards = (cam.center - target) / np.linalg.norm(cam.center - target)
    return m, N, M, arm, colours, sleeve, front, cam, means, target, towards


def test_the_model_finds_layer_gaussians_painted_like_the_arm_in_front_of_them(layered):
    """``model_layer_shows_limbs`` on the model's own Gaussians, posed in the training frames: the
    seen layer Gaussians within 4 cm (in the image plane) of a projected arm Gaussian in frame 0,
    painted in the sleeve's colour over grey cloth, are flagged; no other Gaussian is."""
    from reconstruct.avatar.layer_through import LimbConfig, model_layer_shows_limbs

    m, N, M, arm, colours, sleeve, front, cam, means, target, towards = _arm_over_the_layer(layered)
    # the arm moved over the layer's front in the image, 5 cm nearer the camera (a hand on a skirt)
    means[:N][arm] += target + 0.05 * towards - means[:N][arm].mean(0)
    views = [(cam, means)]
    uv, depth = cam.project(means)
    d = np.min(np.linalg.norm(uv[N:][:, None] - uv[:N][arm][None], axis=2), 1) * depth[N:] / cam.fx
    painted = front & (d < 0.04)
    assert painted.sum() >= 3, painted.sum()
    colours[N:][painted] = sleeve
    seen = np.ones(N + M, bool)
    seen[N:] = front
    with torch.no_grad():
        m.layer_opacity.fill_(1.0)  # opaque cloth: sigmoid(gain x 1)
    # the tiny layer has 16 columns and a coarse body: each Gaussian read alone (no row window), 3
    # arm Gaussians in reach enough
    flags = model_layer_shows_limbs(m, torch.as_tensor(seen), torch.as_tensor(colours), views, LimbConfig(window=0, k=3))
    assert flags.shape == (N + M,) and not flags[:N].any()
    assert flags[N:][painted].mean() > 0.9
    assert not flags[N:][~painted].any()


def test_the_model_finds_layer_gaussians_painted_like_the_arm_behind_it(layered):
    """``model_layer_behind_limbs`` on the model's own Gaussians: the arm moved 15 cm in front of
    the layer's front in frame 0 (a hand on a skirt); the seen layer Gaussians within reach of it
    in the image, painted in the sleeve's colour over grey cloth, lie behind it and are flagged;
    the same with the arm 15 cm behind the layer (inside the skirt) flags nothing, nor does any
    body Gaussian."""
    from reconstruct.avatar.layer_through import BehindConfig, model_layer_behind_limbs

    m, N, M, arm, colours, sleeve, front, cam, means, target, towards = _arm_over_the_layer(layered)
    seen = np.ones(N + M, bool)
    seen[N:] = front
    config = BehindConfig(k=3, reach=0.04)

    def flags_with_arm_at(offset):
        moved = means.copy()
        centre = means[:N][arm].mean(0)  # the arm shrunk to a hand's size about its middle, moved there
        moved[:N][arm] = target + offset * towards + 0.25 * (means[:N][arm] - centre)
        uv, depth = cam.project(moved)
        d = np.min(np.linalg.norm(uv[N:][:, None] - uv[:N][arm][None], axis=2), 1) * depth[N:] / cam.fx
        painted = front & (d < 0.035)
        paint = colours.copy()
        paint[N:][painted] = sleeve
        return model_layer_behind_limbs(m, torch.as_tensor(seen), torch.as_tensor(paint), [(cam, moved)], config), painted

    flags, painted = flags_with_arm_at(0.15)
    assert painted.sum() >= 3, painted.sum()
    assert flags.shape == (N + M,) and not flags[:N].any()
    assert flags[N:][painted].mean() > 0.9
    assert not flags[N:][~painted].any()
    flags, painted = flags_with_arm_at(-0.15)
    assert painted.sum() >= 3 and not flags.any()


def test_the_model_finds_arm_gaussians_that_drew_the_cloth_they_lie_over(layered):
    """``model_limbs_over_cloth`` on the model's own Gaussians: the left arm moved 5 cm in front of
    the layer's front in frame 0 (a hand on a skirt), its Gaussians over the cloth in the image
    painted grey like it; the right arm, in the sleeve's colour away from the cloth, is the limb's
    own colour. The painted ones are flagged, and no other Gaussian; with the cloth in the sleeve's
    colour nothing is."""
    from reconstruct.avatar.limbs_over_cloth import OverClothConfig, model_limbs_over_cloth
    from reconstruct.body.parts import PART_INDEX

    m, N, M, arm, colours, sleeve, front, cam, means, target, towards = _arm_over_the_layer(layered)
    left = np.isin(m.parts()[:N], [PART_INDEX[p] for p in ("upperarm.L", "lowerarm.L", "hand.L")])
    centre = means[:N][left].mean(0)
    means[:N][left] = target + 0.05 * towards + 0.25 * (means[:N][left] - centre)
    seen = np.ones(N + M, bool)
    seen[N:] = front
    with torch.no_grad():
        m.layer_opacity.fill_(1.0)
    config = OverClothConfig(k=3, k_cloth=2, reach=0.04, max_share=1.0)
    views = [(cam, means)]
    uv, depth = cam.project(means)
    luv = uv[N:][front]
    over = np.array([np.sum(np.linalg.norm(luv - p, axis=1) <= 0.04 * cam.fx / d) >= 2
                     for p, d in zip(uv[:N], depth[:N])]) & arm
    assert over.sum() >= 3 and not over[arm & ~left].any(), over.sum()
    paint = colours.copy()
    paint[:N][over] = colours[N:][front].mean(0)
    flags = model_limbs_over_cloth(m, torch.as_tensor(seen), torch.as_tensor(paint), views, config)
    assert flags.shape == (N + M,) and not flags[N:].any()
    assert np.array_equal(flags[:N], over)
    paint[N:] = sleeve
    assert not model_limbs_over_cloth(m, torch.as_tensor(seen), torch.as_tensor(paint), views, config).any()


@pytest.mark.parametrize("rule,on_layer,said", [
    ("layer_behind_limbs", True, "4 garment-layer Gaussians behind an arm or a hand"),
    ("limbs_over_cloth", False, "4 arm and hand Gaussians by the garment layer"),
])
def test_finish_hands_the_fill_what_an_arm_rule_flags(layered, monkeypatch, rule, on_layer, said):
    """Stage I's finish hands the fill the Gaussians an arm rule flags and says how many in its
    note: ``layer_behind_limbs`` (the layer's behind an arm) as unseen, ``limbs_over_cloth`` (the
    arm's by the cloth) as seen but no colour source. With the setting off they are seen sources."""
    import dataclasses

    from reconstruct.avatar.layer_through import ARM_PARTS
    from reconstruct.body.parts import PART_INDEX
    from reconstruct.train import plan as plan_module

    t = layered
    for _ in range(2):
        t.step()
    N = t.model.num_body
    flagged = torch.zeros(t.model.num_gaussians, dtype=torch.bool)
    monkeypatch.setattr(plan_module, rule, lambda state, data, **kw: flagged.clone())
    handed = []
    real = plan_module.fill_unseen_colors
    def fill(state, **kw):
        off = kw.get("not_sources")
        handed.append((state.seen.clone(), torch.zeros_like(state.seen) if off is None else torch.as_tensor(off)))
        return real(state, **kw)

    monkeypatch.setattr(plan_module, "fill_unseen_colors", fill)
    before = t.state.seen.clone()
    t.plan.settings = dataclasses.replace(t.plan.settings, **{rule: False})
    t.plan.finish(t)
    # four the fill gets as seen with the setting off
    seen, not_sources = handed[-1]
    if on_layer:
        pick = N + torch.nonzero(seen[N:]).squeeze(1)
    else:
        arm = torch.as_tensor(np.isin(t.model.parts()[:N], [PART_INDEX[p] for p in ARM_PARTS]))
        pick = torch.nonzero(seen[:N] & ~not_sources[:N] & arm).squeeze(1)
    assert len(pick) >= 4
    flagged[pick[:4]] = True
    t.state.seen.copy_(before)
    t.plan.settings = dataclasses.replace(t.plan.settings, **{rule: True})
    note = t.plan.finish(t)
    seen, not_sources = handed[-1]
    if on_layer:
        assert not bool(seen[flagged].any())
    else:
        assert bool(seen[flagged].all()) and bool(not_sources[flagged].all())
    assert said in note


def test_layer_faced_training_is_the_front_of_the_tube_for_a_front_camera(layered):
    """Against an independent reference: the cosine between each posed layer normal and the
    direction to the camera, in float64, over every training frame."""
    from reconstruct.train.unseen_fill import layer_faced_training

    t = layered
    N = t.model.num_body
    faced = layer_faced_training(t.state, t.data, min_cos=0.2)
    want = torch.zeros_like(faced)
    for i in t.data.frames:
        posed = t.state.posed(i)
        c = torch.as_tensor(t.data.targets[i].camera.center, dtype=torch.float64)
        v = c - posed.means[N:].double()
        cos = (v * posed.normals[N:].double()).sum(1) / v.norm(dim=1)
        want |= cos >= 0.2
    assert torch.equal(faced, want)
    front = t.model.base_normals[N:, 1] < -0.5  # -Y is the front; the tiny scene's cameras look at it
    back = t.model.base_normals[N:, 1] > 0.5
    assert faced[front].float().mean() > 0.9 and faced[back].float().mean() < 0.1


def test_layer_off_person_is_where_a_frame_shows_background(layered):
    """Against an independent reference: each posed layer centre projected with the camera's
    matrices in float64, read on the mask grown by the margin (scipy), over every training frame;
    and a mask emptied over the right half of one frame makes the layer there off the person."""
    import dataclasses

    from scipy.ndimage import binary_dilation

    from reconstruct.train.unseen_fill import layer_off_person

    t = layered
    N = t.model.num_body

    def reference(targets) -> torch.Tensor:
        out = torch.zeros(t.model.num_layer, dtype=torch.bool)
        for i in t.data.frames:
            cam = targets[i].camera
            x = t.state.posed(i).means[N:].detach().double().numpy()
            xc = x @ np.asarray(cam.R, np.float64).T + np.asarray(cam.t, np.float64)
            u = np.floor(cam.fx * xc[:, 0] / xc[:, 2] + cam.cx).astype(int)
            v = np.floor(cam.fy * xc[:, 1] / xc[:, 2] + cam.cy).astype(int)
            grown = binary_dilation(targets[i].mask.numpy() > 0.5, iterations=2)
            h, w = grown.shape
            ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
            on = np.zeros(len(x), bool)
            on[ok] = grown[v[ok], u[ok]]
            out |= torch.as_tensor((xc[:, 2] > 0) & ~on)
        return out

    got = layer_off_person(t.state, t.data, margin=2)
    assert torch.equal(got, reference(t.data.targets))
    i = t.data.frames[0]
    saved = t.data.targets[i]
    try:
        half = saved.mask.clone()
        half[:, half.shape[1] // 2:] = 0
        t.data.targets[i] = dataclasses.replace(saved, mask=half)
        cut = layer_off_person(t.state, t.data, margin=2)
        assert torch.equal(cut, reference(t.data.targets))
        assert int(cut.sum()) > int(got.sum())  # the case is real: the emptied half adds Gaussians
    finally:
        t.data.targets[i] = saved


def test_layer_seen_inside_is_seen_with_the_surface_facing_away_in_every_frame(layered):
    """Against an independent reference (the layer's base normals posed by each Gaussian's own LBS
    matrix in float64, the cosine to each training camera): a seen layer Gaussian whose surface
    faced no camera was seen from inside; the tiny scene's front ones were not, its back ones
    were; unseen ones are never counted."""
    from reconstruct.train.unseen_fill import layer_seen_inside

    t = layered
    N, M = t.model.num_body, t.model.num_layer
    saved = t.state.seen.clone()
    try:
        seen = torch.zeros_like(saved)
        seen[N::2] = True  # every other layer Gaussian "seen", front and back alike
        t.state.seen = seen
        got = layer_seen_inside(t.state, t.data)
        faced = torch.zeros(M, dtype=torch.bool)
        for i in t.data.frames:
            mats = t.model.lbs_matrices(t.state.frame_transforms(i)).detach().double()[N:]
            n = torch.nn.functional.normalize((mats[:, :3, :3] @ t.model.base_normals[N:].double()[..., None])[..., 0], dim=1)
            x = t.state.posed(i).means[N:].detach().double()
            c = torch.as_tensor(t.data.targets[i].camera.center, dtype=torch.float64) - x
            faced |= (c * n).sum(1) >= 0
        assert torch.equal(got, seen[N:] & ~faced)
        front = t.model.base_normals[N:, 1] < -0.5
        back = t.model.base_normals[N:, 1] > 0.5
        assert not got[front].any() and got[back & seen[N:]].float().mean() > 0.9
    finally:
        t.state.seen = saved


def test_the_finish_unsees_layer_gaussians_seen_from_inside(tiny_scene, tiny_config, body):
    """Stage I's finish: with ``layer_seen_inside`` the layer's back Gaussians marked seen become
    unseen and take the fill; without it (older runs, ``paper()``) they stay seen."""
    import dataclasses

    from reconstruct.train.config import Stage1Config

    N = None
    counts = {}
    for on in (True, False):
        # the recount on the person and the untrained rule are off: either would drop these
        # untrained back Gaussians itself
        cfg = dataclasses.replace(tiny_config, layer_seen_inside=on, seen_on_person=False, seen_trained_only=False)
        t = _trainer(tiny_scene, cfg, _layer(body))
        N = t.model.num_body
        back = torch.zeros_like(t.state.seen)
        back[N:] = t.model.base_normals[N:, 1] > 0.5
        t.state.seen = t.state.seen | back
        t.plan.finish(t)
        counts[on] = int((t.state.seen & back).sum())
    assert counts[True] == 0 and counts[False] > 0
    assert Stage1Config().layer_seen_inside and not Stage1Config.paper().layer_seen_inside
    old = Stage1Config().to_dict()
    del old["layer_seen_inside"]
    assert not Stage1Config.from_dict(old).layer_seen_inside


def test_layer_gaussians_a_frame_shows_empty_keep_their_opacity(layered):
    """``empty`` flags leave those layer Gaussians at their learned opacity; the others are filled
    as without them; a wrong shape is named."""
    from reconstruct.train.unseen_fill import fill_unseen_layer_opacity

    t = layered
    m, state = t.model, t.state
    N = m.num_body
    cols = m.layer_rc[:, 1]
    C = m.layer.grid_shape[1]
    saved_seen, saved_op = state.seen.clone(), m.layer_opacity.detach().clone()
    try:
        with torch.no_grad():
            m.layer_opacity.copy_(torch.logit(0.2 + 0.6 * cols.float() / C) / m.config.garment_opacity_gain)
        trained = cols < C // 2
        empty = (cols >= C // 2) & (cols % 2 == 0)
        state.seen[:] = False
        before = m.opacities().detach().clone()
        n = fill_unseen_layer_opacity(state, trained, erosion=0, empty=empty)
        assert n == int((~trained & ~empty).sum())
        after = m.opacities().detach()[N:]
        assert torch.allclose(after[empty], before[N:][empty])
        assert not torch.allclose(after[~trained & ~empty], before[N:][~trained & ~empty])
        with pytest.raises(ValueError, match="empty flags must have shape"):
            fill_unseen_layer_opacity(state, trained, empty=empty[:-1])
    finally:
        state.seen.copy_(saved_seen)
        with torch.no_grad():
            m.layer_opacity.copy_(saved_op)


def test_layer_rings_follow_the_slice_hull_without_bulging_in_depth(body, layer):
    """Each ring is the convex hull of the body slice pushed out by the row's standoff: it is
    deepest straight in front (column 0) and straight behind (column C/2), and within the slice's
    width. The support function used as a radius bulged: over a pair of legs (wide, shallow) its
    points off the front column stood further forward than the front column itself."""
    from reconstruct.avatar.garment_layer import _dense_body

    pts, _ = _dense_body(body)
    R, C = layer.grid_shape
    P = layer.positions.numpy().reshape(R, C, 3)
    for i in range(R):
        assert P[i, :, 1].min() >= P[i, 0, 1] - 0.003, i  # front is -Y
        assert P[i, :, 1].max() <= P[i, C // 2, 1] + 0.003, i
        sl = pts[np.abs(pts[:, 2] - P[i, 0, 2]) < 0.012]
        assert P[i, :, 0].max() - P[i, :, 0].min() >= sl[:, 0].max() - sl[:, 0].min() - 0.01, i


def test_stage2_runs_on_an_avatar_with_a_layer(layered):
    from reconstruct.stage2.config import Stage2Config
    from reconstruct.stage2.plan import start_stage2

    t = layered
    for _ in range(4):
        t.step()
    plan = start_stage2(t, Stage2Config(iters=6, num_azimuths=8, prior_size=48), allow_incomplete=True)
    n = t.model.num_gaussians
    assert t.state.trusted_seen.shape == (n,) and plan.pseudo_colors.shape == (n, 3)
    assert {g["name"] for g in t.optimizer.param_groups} >= {"layer_features", "layer_opacity", "pose_encoder"}
    # the pose map stays a map over the body's atlas
    assert t.model.pose_map(t.state.articulation(1)).shape[0] == 3
    kinds = set()
    for kind in ("given", "canonical", "observation"):
        out = t.plan.steps[kind](t)
        assert not out.skipped
        loss = out.loss()
        assert torch.isfinite(loss)
        kinds.add(kind)
    assert kinds == {"given", "canonical", "observation"}
    out = t.step()
    assert not out.get("skipped")


def test_a_layer_decoded_at_every_other_node_interpolates_its_outputs(body, layer):
    """garment_decode_every=2: the decoder runs at the layer's nodes only; a Gaussian on a node
    decodes as that node, the others as the bilinear blend of their four (checked against the
    decoder called on the node inputs directly), any subset like the whole, and the gradient
    reaches the nodes' features."""
    from reconstruct.avatar.layer_nodes import layer_nodes

    m = AvatarModel(body, _config(garment_decode_every=2), layer=layer)
    rows, cols = layer.grid_shape
    nodes = layer_nodes(rows, cols, layer.tubes, 2)
    N, M = m.num_body, m.num_layer
    assert tuple(m.layer_features.shape) == (1, 8, *nodes.shape)
    assert m.num_nodes == m.node_grid.shape[0] + len(nodes.grid_rc) < m.node_grid.shape[0] + M
    with torch.no_grad():
        m.layer_features.normal_(0, 1.0)  # distinct features per node
        m.decoder.color_residual.zero_()
        raw = m.decode_raw()
        at_nodes = m.decoder(m.layer_decoder_input())
        want = {k: (v[torch.as_tensor(nodes.index)] * torch.as_tensor(nodes.weights, dtype=v.dtype)[..., None]).sum(1)
                for k, v in at_nodes.items()}
        for k in want:
            assert torch.allclose(raw[k][N:], want[k], atol=1e-6), k
        grid_id = torch.as_tensor(nodes.grid_rc[:, 0] * cols + nodes.grid_rc[:, 1])
        assert torch.allclose(raw["color"][N + grid_id], at_nodes["color"], atol=1e-6)
        # between nodes the outputs differ from every node's (not a copy of the nearest)
        off = torch.ones(M, dtype=torch.bool)
        off[grid_id] = False
        assert not torch.isclose(raw["color"][N:][off][:, None], at_nodes["color"][None]).all(-1).any()
        idx = torch.tensor([N + 1, 4, N + M - 1, N + 3, 0])
        sub = m.decode_raw(index=idx)
        for k in raw:
            assert torch.allclose(sub[k], raw[k][idx], atol=1e-6), k
    c = m.canonical()
    c.colors[N:].sum().backward()
    assert float(m.layer_features.grad.abs().sum()) > 0
    with pytest.raises(ValueError, match="garment_decode_every must be an integer in"):
        _config(garment_decode_every=0)


def test_the_layer_is_decoded_at_every_other_node_by_default_and_old_runs_keep_every_gaussian():
    """A new run decodes its layer at every other row and column; a run recorded before the nodes
    existed decoded every layer Gaussian, and its checkpoint's layer feature map has that shape."""
    from reconstruct.train.config import Stage1Config

    assert AvatarConfig().garment_decode_every == 2
    assert Stage1Config().avatar.garment_decode_every == 2
    old = Stage1Config().to_dict()
    del old["avatar"]["garment_decode_every"]
    assert Stage1Config.from_dict(old).avatar.garment_decode_every == 1
    recorded = Stage1Config().to_dict()
    recorded["avatar"]["garment_decode_every"] = 1
    assert Stage1Config.from_dict(recorded).avatar.garment_decode_every == 1


def _float64_inside(t, i: int) -> torch.Tensor:
    """(N+M,) bool, the reference for ``layer_seen_from_inside`` in frame ``i``: the layer's base
    normals posed by each Gaussian's own LBS matrix in float64, pointing away from the camera."""
    N = t.model.num_body
    mats = t.model.lbs_matrices(t.state.frame_transforms(i)).detach().double()
    n = (mats[:, :3, :3] @ t.model.base_normals.double()[..., None])[..., 0]
    x = (mats[:, :3, :3] @ t.model.base_positions.double()[..., None])[..., 0] + mats[:, :3, 3]
    c = torch.as_tensor(t.data.targets[i].camera.center, dtype=torch.float64) - x
    out = (c * n).sum(1) < 0
    out[:N] = False
    return out


def test_layer_seen_from_inside_is_the_far_side_of_the_layer(layered):
    """Against the float64 reference, for all Gaussians and for a subset (a culled decode): only
    layer Gaussians, the back of the skirt for the tiny scene's front camera and never its front."""
    t = layered
    m = t.model
    N = m.num_body
    i = t.data.frames[0]
    mats = m.lbs_matrices(t.state.frame_transforms(i))
    cam = t.data.targets[i].camera.center
    ref = _float64_inside(t, i)
    got = m.layer_seen_from_inside(mats, cam)
    assert torch.equal(got, ref)
    index = torch.arange(N - 50, m.num_gaussians, 3)
    assert torch.equal(m.layer_seen_from_inside(mats, cam, index), ref[index])
    assert not got[:N].any()
    front = m.base_normals[N:, 1] < -0.5
    back = m.base_normals[N:, 1] > 0.5
    assert not got[N:][front].any() and got[N:][back].all()


def test_stage2_given_steps_colour_the_layer_only_from_outside(layered, monkeypatch):
    """``layer_colour_outside``: the given-view loss sends no gradient to the colour of a layer
    Gaussian the view sees from inside (its per-Gaussian colour residual), and the same gradient as
    without the switch to every other Gaussian; without it the inside ones get one too. Stage II
    has it on; Stage II settings recorded before it are off."""
    import dataclasses

    from reconstruct.stage2.config import Stage2Config
    from reconstruct.train import steps as steps_mod

    t = layered
    m = t.model
    frame = t.data.frames[0]
    monkeypatch.setattr(t, "next_frame", lambda: frame)
    cfg = dataclasses.replace(t.config, random_background=False)
    grads = {}
    for on in (True, False):
        step = steps_mod.GivenViewStep(cfg, marks_seen=False, layer_colour_outside=on)
        m.zero_grad(set_to_none=True)
        out = step(t)
        sum(out.weights[k] * v for k, v in out.terms.items()).backward()
        grads[on] = m.decoder.color_residual.grad.detach().abs().sum(1).clone()
    inside = _float64_inside(t, frame)
    assert inside.sum() > 10
    assert torch.all(grads[True][inside] == 0)
    assert (grads[False][inside] > 0).float().mean() > 0.5  # the back of the layer shows through its front
    torch.testing.assert_close(grads[True][~inside], grads[False][~inside])
    assert Stage2Config().layer_colour_outside
    assert not Stage2Config.from_dict({k: v for k, v in Stage2Config().to_dict().items()
                                       if k != "layer_colour_outside"}).layer_colour_outside


def test_layer_training_views_is_the_three_tests_in_one_pass_over_the_frames(layered, monkeypatch):
    """The finish's one pass gives what ``layer_faced_training``, ``layer_seen_inside`` and
    ``layer_off_person`` give one by one, and poses each training frame once (not three times)."""
    from reconstruct.train.unseen_fill import (layer_faced_training, layer_off_person, layer_seen_inside,
                                               layer_training_views)

    t = layered
    N = t.model.num_body
    saved = t.state.seen.clone()
    try:
        seen = torch.zeros_like(saved)
        seen[N::2] = True
        t.state.seen = seen
        one = {"faced": layer_faced_training(t.state, t.data), "seen_inside": layer_seen_inside(t.state, t.data),
               "off_person": layer_off_person(t.state, t.data)}
        calls = []
        real = type(t.state).posed_with_surface_normals
        monkeypatch.setattr(type(t.state), "posed_with_surface_normals",
                            lambda self, i, surface=True: calls.append(i) or real(self, i, surface=surface))
        got = layer_training_views(t.state, t.data, seen_inside=True, off_person=True)
        assert sorted(calls) == sorted(t.data.frames)
        assert got.keys() == one.keys()
        for k in one:
            assert torch.equal(got[k], one[k]), k
        assert one["seen_inside"].any() and one["faced"].any()
        assert set(layer_training_views(t.state, t.data, seen_inside=False, off_person=False)) == {"faced"}
    finally:
        t.state.seen = saved
