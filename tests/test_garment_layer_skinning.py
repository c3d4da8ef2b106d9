"""The garment layer's learned skinning (AvatarModel.layer_skin_weights; docs/loose_clothing.md,
"Learned skinning"): log-factors per bone of the layer's support and tube at knots down the layer,
interpolated to its rows, shared round the tube. Checked against a float64 NumPy reference, finite differences, and by learning a
skinning back from posed positions; the Stage I plan trains it only when asked and Stage II never.
Tiny sizes: layers built from hand-made VolumeHints on the tiny scene's body."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from reconstruct.avatar import AvatarConfig, AvatarModel
from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, landmark_heights
from reconstruct.avatar.model import LAYER_SKIN_SUPPORT
from reconstruct.body.pose import BodyPose


def _config(**kw) -> AvatarConfig:
    """A small avatar; one sector (a factor shared round each tube) unless asked."""
    return AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                        hidden=32, **{"garment_skin_sectors": 1, **kw})


@pytest.fixture(scope="module")
def body(tiny_scene):
    return tiny_scene.body_model()


# the coarse grids below keep the weight filter of 3 rows and 6 columns they were measured with
# (the default keeps its width in metres: on a 6-8 cm grid of 16 columns it would be under a row)
COARSE_DIFFUSION = (3.0, 6.0)


def _skirt(body):
    m = landmark_heights(body)
    return build_garment_layer(body, VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05),
                               cols=16, row_step=0.06, diffusion=COARSE_DIFFUSION)


def _trousers(body):
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=m["ankle"] + 0.05, standoff_hem=0.05, two_legs=True)
    return build_garment_layer(body, hint, cols=16, row_step=0.08, diffusion=COARSE_DIFFUSION)


def _walk_pose(body, seed: int, amount: float = 0.5) -> BodyPose:
    """Random rotations of every bone (a pose far from the canonical one, legs included)."""
    rot = (np.random.default_rng(seed).random((body.num_joints, 3)) - 0.5) * amount
    return BodyPose(rot, np.zeros(3), np.zeros(3))


def _reference(layer, body, logit: np.ndarray, pose: BodyPose, sectors: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Float64 NumPy: the trained weights and the layer's LBS matrices. ``logit`` (K, tubes *
    sectors, S) at K knots spaced evenly from the top row's height to the last row's, interpolated
    with np.interp to each Gaussian's canonical height, then round the tube: Gaussian k is at
    column k % C, tube = column // (C / tubes), at angle a = (column within the tube) / (C / tubes)
    of a turn; sector p's factors hold at a = p / sectors, linear between (wrapping round)."""
    W0 = layer.weights.double().numpy()
    support = np.flatnonzero(W0.max(0) > LAYER_SKIN_SUPPORT)
    rows, C = layer.grid_shape
    Ct = C // layer.tubes
    z = layer.positions.double().numpy()[:, 2]
    knots = np.linspace(z.max(), z.min(), logit.shape[0])
    col = np.arange(len(W0)) % C
    tube, a = col // Ct, (col % Ct) / Ct
    per = np.zeros((len(W0), len(support)))
    for k in range(len(W0)):
        t = a[k] * sectors
        p0 = int(np.floor(t))
        for p, share in ((p0 % sectors, 1 - (t - p0)), ((p0 + 1) % sectors, t - p0)):
            cell = tube[k] * sectors + p
            per[k] += share * np.array([np.interp(-z[k], -knots, logit[:, cell, b]) for b in range(len(support))])
    W = W0.copy()
    W[:, support] *= np.exp(per)
    W /= W.sum(1, keepdims=True)
    T = body.bone_transforms(pose).double().numpy()
    Cn = body.canonical_transforms.double().numpy()
    M = np.einsum("nj,jab->nab", W, T) @ np.linalg.inv(np.einsum("nj,jab->nab", W, Cn))
    return W, M


@pytest.mark.parametrize("make", [_skirt, _trousers], ids=["one tube", "two tubes"])
def test_zero_factors_are_the_built_weights(body, make):
    layer = make(body)
    torch.manual_seed(0)
    m = AvatarModel(body, _config(), layer=layer)
    z = layer.positions[:, 2]
    knots = int(np.ceil(float(z.max() - z.min()) / 0.04 - 1e-9)) + 1  # at most 4 cm apart
    assert torch.equal(m.layer_skin_logit, torch.zeros(knots, layer.tubes, len(m.layer_skin_support)))
    assert torch.allclose(m.layer_skin_weights(), layer.weights, atol=1e-6)
    T = body.bone_transforms(_walk_pose(body, 1)).float()
    M = m.lbs_matrices(T)
    before = blend_formula(m, T)  # the fixed-weight formula: the buffers' weights and inverses
    assert torch.equal(M[:m.num_body], before[:m.num_body])  # the body is untouched
    assert torch.allclose(M[m.num_body:], before[m.num_body:], atol=2e-5)


def blend_formula(m: AvatarModel, T: torch.Tensor) -> torch.Tensor:
    from reconstruct.body.lbs import blend

    return blend(m.skin_weights, T) @ m.canonical_inverse


@pytest.mark.parametrize("make,sectors", [(_skirt, 1), (_trousers, 1), (_skirt, 5), (_trousers, 3)],
                         ids=["one tube", "two tubes", "one tube, 5 sectors", "two tubes, 3 sectors"])
def test_factors_against_a_float64_reference(body, make, sectors):
    layer = make(body)
    m = AvatarModel(body, _config(garment_skin_sectors=sectors), layer=layer)
    assert m.layer_skin_logit.shape[1] == layer.tubes * sectors
    rng = np.random.default_rng(3)
    logit = rng.normal(0, 0.7, tuple(m.layer_skin_logit.shape))
    with torch.no_grad():
        m.layer_skin_logit.copy_(torch.as_tensor(logit))
    pose = _walk_pose(body, 2)
    W, M = _reference(layer, body, logit, pose, sectors)
    assert np.abs(W - layer.weights.double().numpy()).max() > 0.05  # the factors matter
    with torch.no_grad():
        got_w = m.layer_skin_weights().double().numpy()
        T = body.bone_transforms(pose).float()
        got = m.lbs_matrices(T).double().numpy()
        sub = torch.tensor([0, 5, m.num_body, m.num_body + 7, m.num_gaussians - 1])
        got_sub = m.lbs_matrices(T, sub)
    np.testing.assert_allclose(got_w, W, atol=1e-6)
    np.testing.assert_allclose(got[m.num_body:], M, atol=1e-4)
    np.testing.assert_allclose(got_sub.double().numpy(), got[sub.numpy()], atol=1e-6)  # a subset: the same rows


@pytest.mark.parametrize("sectors", [1, 3])
def test_gradient_against_finite_differences(body, sectors):
    layer = _trousers(body)
    m = AvatarModel(body, _config(garment_skin_sectors=sectors), layer=layer).double()
    with torch.no_grad():
        m.layer_skin_logit.normal_(0, 0.3, generator=torch.Generator().manual_seed(4))
    T = body.bone_transforms(_walk_pose(body, 5)).double()
    x = m.base_positions[m.num_body:]
    probe = torch.randn(len(x), 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64)

    def f() -> torch.Tensor:
        M = m.lbs_matrices(T)[m.num_body:]
        return ((M[:, :3, :3] @ x[..., None])[..., 0] + M[:, :3, 3]).mul(probe).sum()

    m.layer_skin_logit.grad = None
    f().backward()
    grad = m.layer_skin_logit.grad.clone()
    assert grad.abs().max() > 1e-3
    eps = 1e-6
    picks = torch.nonzero(grad.abs() > 1e-4)[::max(1, int((grad.abs() > 1e-4).sum()) // 12)][:12]
    assert len(picks) >= 6
    for at in map(tuple, picks.tolist()):
        with torch.no_grad():
            m.layer_skin_logit[at] += eps
            up = f().item()
            m.layer_skin_logit[at] -= 2 * eps
            down = f().item()
            m.layer_skin_logit[at] += eps
        fd = (up - down) / (2 * eps)
        assert abs(fd - grad[at].item()) <= 1e-5 * max(1.0, abs(fd)), (at, fd, grad[at].item())


def test_a_skinning_is_learned_back_from_posed_positions(body):
    """Posed positions made with other factors (smooth down the skirt, like a hem that follows
    the knees less) are fitted from zero factors: the residual falls far below the built weights'."""
    layer = _skirt(body)
    truth = AvatarModel(body, _config(), layer=layer)
    m = AvatarModel(body, _config(), layer=layer)
    K, tubes, S = truth.layer_skin_logit.shape
    with torch.no_grad():
        down = torch.linspace(0, 1, K)[:, None, None]
        truth.layer_skin_logit.copy_(1.5 * down * torch.randn(1, tubes, S, generator=torch.Generator().manual_seed(7)))
    poses = [body.bone_transforms(_walk_pose(body, s, 0.6)).float() for s in range(3)]
    x = m.base_positions[m.num_body:]

    def posed(model, T):
        M = model.lbs_matrices(T)[model.num_body:]
        return (M[:, :3, :3] @ x[..., None])[..., 0] + M[:, :3, 3]

    with torch.no_grad():
        target = [posed(truth, T) for T in poses]
    err = lambda: float(sum((posed(m, T) - y).norm(dim=1).mean() for T, y in zip(poses, target)) / len(poses))
    with torch.no_grad():
        start = err()
    assert start > 0.005  # the built weights miss the target by more than 5 mm on average
    opt = torch.optim.Adam([m.layer_skin_logit], lr=0.05)
    for _ in range(300):
        opt.zero_grad()
        loss = sum((posed(m, T) - y).square().sum(1).mean() for T, y in zip(poses, target))
        loss.backward()
        opt.step()
    with torch.no_grad():
        assert err() < 0.1 * start


def test_stage1_trains_it_only_when_asked_and_stage2_never(tiny_scene, tiny_config, body, tmp_path):
    from reconstruct.stage2.config import Stage2Config
    from reconstruct.stage2.plan import start_stage2
    from reconstruct.train.checkpoint import load_checkpoint
    from reconstruct.train.trainer import Trainer

    from reconstruct.train.config import Stage1Config

    assert Stage1Config().lr_layer_skinning == 0.01  # the default trains it
    record = Stage1Config().to_dict()
    del record["lr_layer_skinning"]
    assert Stage1Config.from_dict(record).lr_layer_skinning == 0.0  # a run recorded before it: the built weights
    assert Stage1Config().avatar.garment_skin_sectors == 12
    del record["avatar"]["garment_skin_sectors"]
    assert Stage1Config.from_dict(record).avatar.garment_skin_sectors == 1  # recorded before the sectors
    fixed = Trainer(tiny_scene, dataclasses.replace(tiny_config, lr_layer_skinning=0.0), garment_layer=_skirt(body))
    assert "layer_skinning" not in {g["name"] for g in fixed.optimizer.param_groups}
    assert "layer_skinning" not in fixed.plan.steps["given"](fixed).terms
    fixed.step()
    assert torch.equal(fixed.model.layer_skin_logit, torch.zeros_like(fixed.model.layer_skin_logit))
    assert not fixed.model.layer_skin_logit.requires_grad  # frozen: its weights are reused step to step

    cfg = dataclasses.replace(tiny_config, lr_layer_skinning=0.05)
    t = Trainer(tiny_scene, cfg, garment_layer=_skirt(body))
    assert "layer_skinning" in {g["name"] for g in t.optimizer.param_groups}
    assert "layer_skinning" in t.plan.steps["given"](t).terms
    assert t.model.layer_skin_logit.requires_grad
    for _ in range(3):
        assert not t.step().get("skipped")
    learned = t.model.layer_skin_logit.detach().clone()
    assert learned.abs().max() > 1e-3
    # checkpoints carry it; a checkpoint saved before it existed loads as zero factors
    path = t.save(tmp_path / "checkpoint.pt")
    state = load_checkpoint(path)
    t2 = Trainer(tiny_scene, cfg, garment_layer=_skirt(body))
    t2.load_state_dict(state, str(path))
    assert torch.equal(t2.model.layer_skin_logit, learned)
    old = dict(state["avatar"]["model"])
    del old["layer_skin_logit"]
    t2.state.load_state_dict({**state["avatar"], "model": old})
    assert torch.equal(t2.model.layer_skin_logit, torch.zeros_like(learned))
    # Stage II keeps what Stage I learned
    plan = start_stage2(t, Stage2Config(iters=4, num_azimuths=8, prior_size=48), allow_incomplete=True)
    assert plan is not None
    assert "layer_skinning" not in {g["name"] for g in t.optimizer.param_groups}
    assert not t.model.layer_skin_logit.requires_grad
    t.step()
    assert torch.equal(t.model.layer_skin_logit.detach(), learned)


def test_hem_rows_stay_together_whatever_the_factors(body):
    """The hem's rows are 5 mm apart: with a factor per row they could follow different bones and
    tear off (a trained dress stretched its last rows' edges 12x in the walk). Factors at knots
    4 cm apart, interpolated, keep every row's neighbour within 2.5 times its rest distance in
    the walk even for large random factors."""
    import dataclasses as dc

    from reconstruct.body.novel_poses import walk_cycle

    layer = _skirt(body)
    m = AvatarModel(body, _config(), layer=layer)
    with torch.no_grad():
        m.layer_skin_logit.normal_(0, 1.0, generator=torch.Generator().manual_seed(8))
        learned = dc.replace(layer, weights=m.layer_skin_weights().float())
    walk = walk_cycle(body, 6)
    built, trained = layer.max_neighbour_stretch(body, walk), learned.max_neighbour_stretch(body, walk)
    # measured: built 1.02, knots 4 cm apart 1.79; with knots 1 cm apart (the hem rows' factors
    # nearly free) 4.17
    assert built < 1.1 and trained < 2.5, (built, trained)


def test_prior_with_sectors_against_its_formula(body):
    """The prior: mean square + mean squared change between knots + (sectors) between
    neighbouring sectors round each tube, wrapping round; a factor the same all round the tube
    pays nothing for the sectors."""
    layer = _trousers(body)
    m = AvatarModel(body, _config(garment_skin_sectors=4), layer=layer)
    K, cells, S = m.layer_skin_logit.shape
    rng = np.random.default_rng(9)
    logit = rng.normal(0, 0.5, (K, cells, S))
    with torch.no_grad():
        m.layer_skin_logit.copy_(torch.as_tensor(logit))
    ring = logit.reshape(K, layer.tubes, 4, S)
    want = (np.mean(logit ** 2) + np.mean((logit[1:] - logit[:-1]) ** 2)
            + np.mean((ring - np.roll(ring, 1, axis=2)) ** 2))
    assert abs(m.layer_skinning_prior().item() - want) < 1e-5 * want
    same = np.repeat(rng.normal(0, 0.5, (K, layer.tubes, 1, S)), 4, axis=2).reshape(K, cells, S)
    with torch.no_grad():
        m.layer_skin_logit.copy_(torch.as_tensor(same))
    plain = np.mean(same ** 2) + np.mean((same[1:] - same[:-1]) ** 2)
    assert abs(m.layer_skinning_prior().item() - plain) < 1e-5 * plain
    with pytest.raises(ValueError, match="garment_skin_sectors"):
        AvatarConfig(garment_skin_sectors=0)
    # at most one sector per column: the trousers' tubes have 8 columns each
    assert AvatarModel(body, _config(garment_skin_sectors=12), layer=layer).layer_skin_logit.shape[1] == 2 * 8


def test_frozen_skinning_is_kept_until_the_factors_change(body):
    """Without a gradient the layer's weights and inverses are computed once and reused; an
    in-place change of the factors (an optimiser's step, a loaded checkpoint) or a new dtype
    recomputes them; with a gradient they are always fresh (and carry it)."""
    layer = _skirt(body)
    m = AvatarModel(body, _config(garment_skin_sectors=2), layer=layer)
    T = body.bone_transforms(_walk_pose(body, 3)).float()
    calls = []
    real = m.layer_skin_weights

    def counted():
        calls.append(1)
        return real()

    m.layer_skin_weights = counted
    with torch.no_grad():
        a = m.lbs_matrices(T)
        b = m.lbs_matrices(T)
        assert len(calls) == 1 and torch.equal(a, b)
        m.layer_skin_logit.normal_(0, 0.5, generator=torch.Generator().manual_seed(1))
        c = m.lbs_matrices(T)
        assert len(calls) == 2 and not torch.allclose(a, c, atol=1e-4)
        m.load_state_dict({**m.state_dict(), "layer_skin_logit": torch.zeros_like(m.layer_skin_logit)})
        assert torch.allclose(m.lbs_matrices(T), a, atol=1e-6) and len(calls) == 3
    opt = torch.optim.Adam([m.layer_skin_logit], lr=0.1)
    loss = m.lbs_matrices(T)[m.num_body:, :3, 3].sum()
    assert len(calls) == 4
    loss.backward()
    assert m.layer_skin_logit.grad.abs().max() > 0
    opt.step()
    with torch.no_grad():
        d = m.lbs_matrices(T)
    assert len(calls) == 5 and not torch.allclose(d, a, atol=1e-4)
    md = m.double()
    with torch.no_grad():
        assert md.lbs_matrices(T.double()).dtype == torch.float64 and len(calls) == 6


def test_sectors_varying_smoothly_round_the_tube_keep_it_together(body):
    """Twelve sectors: factors that vary round the tube as a trained coat's do (once round: the
    front panels against the back, with the prior's smoothness between sectors) stretch the walk
    less than 3x even when large (sigma 1); measured 2.57 (one sector, random per knot: 1.79).
    Factors drawn independently per sector (no smoothness) reach 4.5x."""
    import dataclasses as dc

    from reconstruct.body.novel_poses import walk_cycle

    layer = _skirt(body)
    m = AvatarModel(body, _config(garment_skin_sectors=12), layer=layer)
    K, P, S = m.layer_skin_logit.shape
    g = torch.Generator().manual_seed(8)
    a, b, c = (torch.randn(K, 1, S, generator=g) for _ in range(3))
    theta = torch.arange(P) * 2 * math.pi / P
    with torch.no_grad():
        m.layer_skin_logit.copy_((a + b * torch.cos(theta)[:, None] + c * torch.sin(theta)[:, None]) / math.sqrt(3))
        learned = dc.replace(layer, weights=m.layer_skin_weights().float())
    walk = walk_cycle(body, 6)
    assert learned.max_neighbour_stretch(body, walk) < 3.0
