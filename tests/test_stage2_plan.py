"""Stage II plan: the switch of a trainer that finished Stage I, pose injection starting from Stage I's
output, dual-space guidance steps, schedule, checkpoints and errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch


@pytest.fixture
def stage1(tiny_scene, tiny_config, tmp_path):
    from reconstruct.train.trainer import Trainer

    s = Trainer(tiny_scene, tiny_config, tmp_path / "run")
    (tmp_path / "run").mkdir()
    for _ in range(tiny_config.iters):
        s.step()
    return s


def _start(trainer, cfg):
    from reconstruct.stage2.plan import start_stage2

    start_stage2(trainer, cfg)
    return trainer


def _cfg(**kw):
    from reconstruct.stage2.config import Stage2Config

    base = dict(iters=12, num_azimuths=12, prior_size=48)
    base.update(kw)
    return Stage2Config(**base)


def test_pose_injection_starts_where_stage1_ended(stage1):
    """P = S + E(P_uv) with E's last layer at zero: the first Stage II Gaussians are Stage I's."""
    with torch.no_grad():
        before = stage1.model.canonical()
    s2 = _start(stage1, _cfg())
    state = s2.state
    assert s2.stage == 2 and state.model.pose_encoder is not None
    with torch.no_grad():
        for frame in (None, 0, 3):
            after = state.canonical(frame)
            assert torch.allclose(after.colors, before.colors, atol=1e-6)
            assert torch.allclose(after.means, before.means, atol=1e-6)
    # the pose map is zero in the canonical pose and not for a video frame
    assert float(state.model.pose_map(state.articulation(None)).abs().max()) < 1e-5
    assert float(state.model.pose_map(state.articulation(1)).abs().max()) > 1e-2


def test_stage2_steps_change_unseen_colours_towards_propagation(stage1):
    s1_steps = stage1.step_count
    s2 = _start(stage1, _cfg(given_view_ratio=0.0, iters=20, lambda_sds=1.0, progressive=False,
                             lr_decoder=3e-3, lr_features=1e-3, lr_milestones=()))
    plan = s2.plan
    assert plan.spaces and plan.spaces[0].frame is None
    unseen = ~s2.state.trusted_seen
    assert unseen.any()
    # a pseudo-target far from the avatar's colours: unseen Gaussians must move towards it
    plan.pseudo_colors[unseen] = torch.tensor([1.0, 0.0, 0.0])
    with torch.no_grad():
        err0 = float((s2.state.canonical(None).colors - plan.pseudo_colors)[unseen].abs().mean())
    kinds = set()
    while not s2.done:
        out = s2.step()
        assert not out.get("skipped")
        assert math.isfinite(out["loss"])
        kinds.add(out["step_kind"])
    assert kinds == {"canonical", "observation"}
    with torch.no_grad():
        err1 = float((s2.state.canonical(None).colors - plan.pseudo_colors)[unseen].abs().mean())
    assert err1 < err0 * 0.9, (err0, err1)
    assert s2.stage_step == 20 and s2.step_count == s1_steps + 20 and s2.stage_starts[2] == s1_steps


def test_ratios_and_ablation_switches(stage1):
    plan = _start(stage1, _cfg(given_view_ratio=0.5, canonical_ratio=1.0, iters=40)).plan
    rng = np.random.default_rng(0)
    kinds = [plan.next_kind(rng) for _ in range(400)]
    assert "observation" not in kinds
    assert abs(kinds.count("given") / 400 - 0.5) < 0.1
    plan.update_settings(_cfg(canonical_sds=False), stage1.state)
    assert "canonical" not in {plan.next_kind(rng) for _ in range(100)}
    plan.update_settings(_cfg(canonical_sds=False, observation_sds=False), stage1.state)
    assert {plan.next_kind(rng) for _ in range(50)} == {"given"}


def test_schedule_halves_lambda_sds():
    c = _cfg(lambda_sds=0.3, sds_t0=100, sds_k=100, epoch_steps=5)  # Eq. 14: halved from epoch t0 + k
    assert c.sds_weight(0) == 0.3 and c.sds_weight(999) == 0.3
    assert c.sds_weight(1000) == pytest.approx(0.15) and c.sds_weight(1500) == pytest.approx(0.075)
    assert _cfg(progressive=False).sds_weight(10 ** 6) == 0.3


def test_checkpoint_roundtrip_resumes_stage2(stage1, tmp_path):
    from reconstruct.run_folder import RunFolder
    from reconstruct.stage2.plan import Stage2Plan
    from reconstruct.train.checkpoint import STAGE1_CHECKPOINT_NAME

    s2 = _start(stage1, _cfg())
    assert (stage1.run_dir / STAGE1_CHECKPOINT_NAME).exists()
    for _ in range(4):
        s2.step()
    s2.save()
    back = RunFolder(stage1.run_dir).resume(stage1.scene)
    assert isinstance(back.plan, Stage2Plan) and back.stage == 2
    assert back.stage_step == 4 and back.step_count == s2.step_count
    assert [len(s.views) for s in back.plan.spaces] == [len(s.views) for s in s2.plan.spaces]
    assert [v.unseen for v in back.plan.selected_views] == [v.unseen for v in s2.plan.selected_views]
    assert torch.equal(back.state.trusted_seen, s2.state.trusted_seen)
    with torch.no_grad():
        assert torch.allclose(back.state.canonical(2).colors, s2.state.canonical(2).colors)
    for _ in range(3):  # same RNG state: the same next steps
        a, b = s2.step(), back.step()
        assert a["step_kind"] == b["step_kind"] and a["loss"] == pytest.approx(b["loss"], rel=1e-5)


def test_every_view_seen_skips_guidance(stage1):
    stage1.state.seen[:] = True
    s2 = _start(stage1, _cfg())
    assert s2.plan.sds_note and "already seen" in s2.plan.sds_note
    assert {s2.step()["step_kind"] for _ in range(5)} == {"given"}


def test_incomplete_stage1_is_refused(tiny_scene, tiny_config):
    from reconstruct.stage2.guidance import Stage2Error
    from reconstruct.stage2.plan import start_stage2
    from reconstruct.train.trainer import Trainer

    s = Trainer(tiny_scene, tiny_config)
    with pytest.raises(Stage2Error, match="taken no step"):
        start_stage2(s, _cfg())
    s.step()
    with pytest.raises(Stage2Error, match="incomplete"):
        start_stage2(s, _cfg())
    assert s.stage == 1


def test_config_errors():
    from reconstruct.stage2.config import Stage2Config

    with pytest.raises(ValueError, match=r"threshold must be in \(0, 1\)"):
        Stage2Config(visibility_threshold=1.0)
    with pytest.raises(ValueError, match="prior-path"):
        Stage2Config(prior="zero123")
    with pytest.raises(ValueError, match="unknown prior"):
        Stage2Config(prior="dreams")


def test_framed_camera_crops_to_points():
    from reconstruct.camera import Camera
    from reconstruct.stage2.guidance import framed_camera

    cam = Camera.orbit(30.0, 0.0, 5.0, (0, 0, 1), width=128, height=128, fov_y_deg=30.0)
    pts = torch.as_tensor(np.random.default_rng(0).uniform(-0.4, 0.4, (200, 3)) + [0, 0, 1])
    f = framed_camera(cam, pts, 64, margin=0.1)
    xc = pts.numpy() @ f.R.T + f.t
    u = f.K[0, 0] * xc[:, 0] / xc[:, 2] + f.K[0, 2]
    v = f.K[1, 1] * xc[:, 1] / xc[:, 2] + f.K[1, 2]
    assert u.min() > 0 and v.min() > 0 and u.max() < 64 and v.max() < 64
    assert max(u.max() - u.min(), v.max() - v.min()) > 64 * 0.75  # the points fill the crop


def test_stage2_with_zero123_prior_runs_dual_space_steps(stage1, tmp_path):
    """The Zero123 SDS prior (tiny random model, saved and loaded in diffusers layout) in the
    dual-space loop: guidance steps take place in both spaces, on white, and change the decoder."""
    pytest.importorskip("diffusers")
    from reconstruct.priors.zero123_random import save_random_zero123

    folder = save_random_zero123(tmp_path / "zero123-tiny", size="tiny", seed=0)
    s2 = _start(stage1, _cfg(prior="zero123", prior_path=str(folder), given_view_ratio=0.0, prior_size=64, iters=4))
    plan = s2.plan
    assert "Zero123" in plan.prior.describe()
    assert float(plan.guidance_background.min()) == 1.0 and float(plan.canonical_reference[0, 0].min()) == 1.0
    before = [p.detach().clone() for p in s2.model.decoder.parameters()]
    kinds = set()
    while not s2.done:
        out = s2.step()
        assert not out.get("skipped") and math.isfinite(out["loss"])
        kinds.add(out["step_kind"])
    assert kinds <= {"canonical", "observation"} and kinds
    changed = sum(float((a - p.detach()).abs().max()) > 0 for a, p in zip(before, s2.model.decoder.parameters()))
    assert changed > 0


def test_zero123_prior_loads_on_the_training_device(stage1, tmp_path, monkeypatch):
    """On a machine with CUDA, a run trained on the CPU keeps its Zero123 on the CPU (the loader's
    own default would be CUDA in bf16, and the SDS loss would land on another device than the rest).
    CUDA is faked as present: loading it there would fail on this machine."""
    pytest.importorskip("diffusers")
    from reconstruct.priors.zero123_random import save_random_zero123

    folder = save_random_zero123(tmp_path / "zero123-tiny", size="tiny", seed=0)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    s2 = _start(stage1, _cfg(prior="zero123", prior_path=str(folder), given_view_ratio=0.0, prior_size=64, iters=1))
    assert s2.plan.prior.c.device == torch.device("cpu") and s2.plan.prior.c.dtype == torch.float32


def test_snapshots_show_the_flags_stage2_uses(stage1):
    """The renderer's visibility mode shows Stage I's flags in Stage I and the eroded ones that
    drove view selection in Stage II."""
    assert (stage1.make_snapshot().visibility == stage1.state.seen.numpy()).all()
    s2 = _start(stage1, _cfg())
    snap = s2.make_snapshot()
    assert (snap.visibility == s2.state.trusted_seen.numpy()).all()
    assert snap.visibility.sum() < int(s2.state.seen.sum())  # erosion removed the boundary


def test_stage2_starts_alike_in_the_same_process_and_from_a_reloaded_stage1(stage1):
    """The pose encoder is seeded from the run's seed and the stage's step mix and frame order start
    over: Stage II right after Stage I and Stage II on the reloaded Stage I checkpoint take the same steps."""
    from reconstruct.run_folder import RunFolder

    stage1.save()
    reloaded = RunFolder(stage1.run_dir).resume(stage1.scene)
    a, b = _start(stage1, _cfg()), _start(reloaded, _cfg())
    for _ in range(4):
        x, y = a.step(), b.step()
        assert x["step_kind"] == y["step_kind"] and x["loss"] == pytest.approx(y["loss"], rel=1e-6)


def test_texture_space_pseudo_colour_term(stage1):
    """lambda_pseudo_color > 0: guidance steps log the per-Gaussian colour term towards the
    pseudo-appearance (the untrusted Gaussians only, or every one with pseudo_color_all)."""
    s2 = _start(stage1, _cfg(given_view_ratio=0.0, iters=4, lambda_pseudo_color=1.0, progressive=False))
    plan = s2.plan
    with torch.no_grad():
        colors = s2.state.canonical(None).colors
        free = ~s2.state.trusted_seen
        expect = float(((colors[free] - plan.pseudo_colors[free]) ** 2).mean())
    out = s2.step()
    assert out["step_kind"] in ("canonical", "observation")
    assert out["pseudo_color"] == pytest.approx(expect, rel=1e-3, abs=1e-7)


def test_pseudo_appearance_reads_stage1s_colour_sources(stage1):
    """Stage II carries colours from the sources of Stage I's fill (``AvatarState.colour_sources``):
    a trusted Gaussian Stage I took out of them is carried nowhere and keeps its own colour; with
    the flags unset (runs from before them) every trusted Gaussian is a source."""
    from reconstruct.body.parts import PART_INDEX

    state = stage1.state
    assert state.colour_sources is not None and state.colour_sources.shape == state.seen.shape
    s2 = _start(stage1, _cfg())
    plan, model = s2.plan, s2.state.model
    nb = model.neighbours()
    trusted = state.trusted_seen.clone()
    torso = torch.as_tensor(model.parts() == PART_INDEX["torso"])
    red = trusted & torso
    assert int(red.sum()) > 20 and bool((torso & ~trusted).any())
    colors = torch.full((model.num_gaussians, 3), 0.5)
    colors[red] = torch.tensor([1.0, 0.0, 0.0])
    # what the images show under the tiny avatar's chin is no colour source either: left out here
    state.occluded_colors = None
    state.colour_sources = None
    before = plan.propagated_colors(model, state, colors, nb)
    assert float(before[torso & ~trusted, 0].max()) > 0.9  # the red torso carried round
    state.colour_sources = ~red
    after = plan.propagated_colors(model, state, colors, nb)
    assert torch.allclose(after[red], colors[red])  # kept, not repainted
    unseen_torso = torso & ~trusted
    assert float((after[unseen_torso] - 0.5).abs().max()) < 1e-6  # and carried nowhere


def test_colour_sources_round_trip_through_the_state_dict(stage1):
    from reconstruct.avatar.state import AvatarState

    state = stage1.state
    flags = torch.zeros_like(state.seen)
    flags[::3] = True
    state.colour_sources = flags
    d = state.state_dict()
    other = AvatarState(state.body, state.model, state.poses)
    other.load_state_dict(d)
    assert torch.equal(other.colour_sources, flags)
    d.pop("colour_sources")  # a checkpoint from before the flags: every seen Gaussian is a source
    other.load_state_dict(d)
    assert other.colour_sources is None and torch.equal(other.source_flags(), state.seen)
    d["colour_sources"] = flags[:-1]
    with pytest.raises(ValueError, match="colour_sources has shape"):
        other.load_state_dict(d)


def _colours_round_trip(state, key: str, colours: torch.Tensor, where: torch.Tensor) -> None:
    """Per-Gaussian colours of the state (``key``: ``cut_colors``, ``occluded_colors``, ``hair_colors``; NaN but
    ``where``) are saved and loaded with it and copied by ``frozen``; a checkpoint without them
    (from before them) loads None, one of the wrong shape is refused."""
    from reconstruct.avatar.state import AvatarState

    setattr(state, key, colours.clone())
    d = state.state_dict()
    other = AvatarState(state.body, state.model, state.poses)
    other.load_state_dict(d)
    got = getattr(other, key)
    assert torch.equal(got.isnan(), colours.isnan()) and torch.equal(got[where], colours[where])
    assert torch.equal(getattr(state.frozen(), key)[where], colours[where])
    d.pop(key)
    other.load_state_dict(d)
    assert getattr(other, key) is None
    d[key] = colours[:-1]
    with pytest.raises(ValueError, match=f"{key} has shape"):
        other.load_state_dict(d)


def _pseudo_with_and_without(stage1, key: str, colours: torch.Tensor, untrusted: torch.Tensor | None = None):
    """Stage II's pseudo-appearance of random colours with the state's ``key`` colours given, and
    without them, on the trusted flags less ``untrusted``: (with, without, those trusted flags)."""
    from reconstruct.appearance.pseudo_appearance import pseudo_appearance

    s2 = _start(stage1, _cfg())
    model = s2.state.model
    colors = torch.rand((model.num_gaussians, 3), generator=torch.Generator().manual_seed(0))
    s2.state.colour_sources = None
    trusted = s2.state.trusted_seen.clone()
    if untrusted is not None:
        trusted[untrusted] = False
    runs = []
    for given in (colours, None):
        setattr(s2.state, key, given)
        runs.append(pseudo_appearance(s2.state, trusted, colors, model.neighbours(), 0, grazing_rule=False))
    return runs[0], runs[1], trusted


def test_cut_colours_round_trip_and_reach_stage2s_pseudo_appearance(stage1):
    """``AvatarState.cut_colors`` (Stage I's finish: the colours for the Gaussians in no training
    image) are saved and loaded with the state, copied by ``frozen``, and Stage II's
    pseudo-appearance paints the body past the cut with them, as Stage I's fill did."""
    from reconstruct.body.parts import PART_INDEX

    state = stage1.state
    assert state.cut_colors is not None and torch.isnan(state.cut_colors).all()  # the whole person in view
    model = state.model
    legs = torch.as_tensor(np.isin(model.parts(), [PART_INDEX[p] for p in ("shin.L", "shin.R", "foot.L", "foot.R")]))
    cut = torch.full((model.num_gaussians, 3), float("nan"))
    cut[legs] = torch.tensor([0.1, 0.2, 0.7])
    _colours_round_trip(state, "cut_colors", cut, legs)  # absent: nothing counted out of view
    s2 = _start(stage1, _cfg())
    s2.state.cut_colors = cut.clone()
    plan, nb = s2.plan, model.neighbours()
    colors = torch.rand((model.num_gaussians, 3), generator=torch.Generator().manual_seed(0))
    with_cut = plan.propagated_colors(model, s2.state, colors, nb)
    s2.state.cut_colors = None
    without = plan.propagated_colors(model, s2.state, colors, nb)
    painted = legs & ~s2.state.trusted_seen
    assert bool(painted.any())
    assert torch.allclose(with_cut[painted], torch.tensor([0.1, 0.2, 0.7]).expand(int(painted.sum()), 3), atol=1e-6)
    assert torch.equal(with_cut[~painted], without[~painted])


def test_occluded_colours_round_trip_and_reach_stage2s_pseudo_appearance(stage1):
    """``AvatarState.occluded_colors`` (Stage I's finish: what the images show where a neck they
    never show lies) are saved and loaded with the state, copied by ``frozen``, and Stage II's
    pseudo-appearance reads them as Stage I's fill did."""
    from reconstruct.body.parts import PART_INDEX

    state = stage1.state
    assert state.occluded_colors is not None  # the finish read them
    model = state.model
    neck = torch.as_tensor(model.parts() == PART_INDEX["neck"])
    occ = torch.full((model.num_gaussians, 3), float("nan"))
    occ[neck] = torch.tensor([0.3, 0.6, 0.2])
    _colours_round_trip(state, "occluded_colors", occ, neck)
    # a neck with no trusted Gaussian (a photo's, under the chin): its front takes them
    runs = _pseudo_with_and_without(stage1, "occluded_colors", occ, untrusted=neck)[:2]
    front = neck & (model.base_normals.cpu()[:, 1] < 0)
    near = ((runs[0][front] - torch.tensor([0.3, 0.6, 0.2])).abs().amax(1) < 0.02).float().mean()
    assert near > 0.8
    assert ((runs[1][front] - torch.tensor([0.3, 0.6, 0.2])).abs().amax(1) < 0.02).float().mean() < 0.05


def test_hair_colours_round_trip_and_reach_stage2s_pseudo_appearance(stage1):
    """``AvatarState.hair_colors`` (Stage I's finish: hair worn down, read in the images) are saved
    and loaded with the state, copied by ``frozen``, and Stage II's pseudo-appearance gives them to
    the unseen Gaussians they cover, as Stage I's fill did."""
    from reconstruct.body.parts import PART_INDEX

    state = stage1.state
    assert state.hair_colors is not None  # the finish read the frames (the tiny scene's hair: none)
    model = state.model
    parts = model.parts()
    back = torch.as_tensor(np.isin(parts, [PART_INDEX["neck"], PART_INDEX["torso"]])) & (model.base_positions.cpu()[:, 1] > 0)
    hair = torch.full((model.num_gaussians, 3), float("nan"))
    hair[back] = torch.tensor([0.4, 0.25, 0.1])
    _colours_round_trip(state, "hair_colors", hair, back)
    *runs, trusted = _pseudo_with_and_without(stage1, "hair_colors", hair)
    painted = back & ~trusted
    assert int(painted.sum()) > 50
    assert torch.allclose(runs[0][painted], torch.tensor([0.4, 0.25, 0.1]).expand(int(painted.sum()), 3), atol=1e-6)
    assert ((runs[1][painted] - torch.tensor([0.4, 0.25, 0.1])).abs().amax(1) < 0.02).float().mean() < 0.05
    assert torch.equal(runs[0][~painted], runs[1][~painted])
