"""Edits (reconstruct/edits, issue 22): selections, operations, undo, the lock under further
training in both stages, painted visibility and Stage II's view selection, the run folder's edits
file and the headless ``edit`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from reconstruct.edits import EditsError, Erase, Lock, PaintSeen, PaintUnseen, Recolour, Redo
from reconstruct.edits.session import EditSession
from tiny_runs import train_tiny

LOCK_TOL = 0.0  # locked Gaussians' decoded attributes are bit-identical after further training


@pytest.fixture
def trained(tiny_scene, tiny_config, tmp_path):
    from reconstruct.train.trainer import Trainer

    run = tmp_path / "run"
    run.mkdir()
    t = Trainer(tiny_scene, tiny_config, run)
    for _ in range(12):
        t.step()
    return t


def _stage2_cfg(**kw):
    from reconstruct.stage2.config import Stage2Config

    base = dict(iters=40, num_azimuths=12, prior_size=48)
    base.update(kw)
    return Stage2Config(**base)


def _decoded(state, frame=None):
    with torch.no_grad():
        c = state.canonical(frame)
    return {k: getattr(c, k).clone() for k in ("means", "normals", "colors", "scales")}


def _snap_arrays(snap):
    return {k: getattr(snap, k).copy() for k in ("means", "scales", "rotations", "colors", "opacities", "normals",
                                                  "visibility")}


def _torso(state):
    from reconstruct.edits.selection import part_mask

    return part_mask(state.model.parts(), "torso")


# ----- selection -----------------------------------------------------------------------------
def test_part_rect_through_grow_shrink(trained):
    from reconstruct.camera import Camera

    state = trained.state
    s = EditSession(state)
    head = s.select_part("head").copy()
    assert head.any() and not head.all()
    assert (state.model.parts()[head] == 1).all()
    with pytest.raises(ValueError, match="no body part"):
        s.select_part("tail")
    grown = s.grow(2).copy()
    assert grown.sum() > head.sum() and (grown >= head).all()
    s.shrink(2)
    assert (s.selection <= grown).all()
    s.invert()
    assert s.selection.sum() == state.num_gaussians - (s.selection == 0).sum()
    s.clear()
    assert not s.selection.any()
    # a rectangle over the whole front view: visible surface only vs through the body
    snap = state.snapshot("observation", 0)
    cam = tiny_scene_camera = trained.scene.frames[0].camera
    visible = s.select_rect(cam, snap, (0, 0, cam.width, cam.height)).copy()
    through = s.select_rect(cam, snap, (0, 0, cam.width, cam.height), through=True).copy()
    assert 0 < visible.sum() < through.sum() and (visible <= through).all()
    # the visible ones face the camera
    from reconstruct.body.lbs import apply_normals, apply_points

    M = state.model.lbs_matrices(state.frame_transforms(0))
    x, n = apply_points(M, state.model.base_positions), apply_normals(M, state.model.base_normals)
    centre = torch.as_tensor(tiny_scene_camera.center, dtype=x.dtype)
    facing = ((x - centre) * n).sum(1) < 0  # the body surface's normals
    assert facing[torch.as_tensor(visible)].float().mean() > 0.7  # 64 px, grazing outline
    assert facing[torch.as_tensor(through & ~visible)].float().mean() < 0.5
    # highlight: one flag per snapshot row
    hl = s.highlight(snap)
    assert hl.dtype == np.uint8 and hl.shape == (len(snap),) and hl.sum() == through.sum()
    # lasso covering the image = rectangle
    lasso = s.select_lasso(cam, snap, [(0, 0), (cam.width, 0), (cam.width, cam.height), (0, cam.height)]).copy()
    assert (lasso == visible).all()
    Camera  # noqa: B018


# ----- operations and undo -------------------------------------------------------------------
@pytest.mark.parametrize("op", [Erase(), Lock(), Recolour(40, 0.5, 0.8), PaintSeen(), PaintUnseen(), Redo()],
                         ids=lambda o: o.name)
def test_undo_restores_the_avatar_bit_exactly(trained, op):
    state = trained.state
    before_obs = _snap_arrays(state.snapshot("observation", 1))
    before_can = _snap_arrays(state.snapshot("canonical"))
    before_flags = state.seen_flags().clone()
    s = EditSession(state)
    s.select_part("torso")
    entry = s.apply(op)
    assert entry.count == _torso(state).sum() and len(s.entries()) == 1
    after = _snap_arrays(state.snapshot("observation", 1)) if not isinstance(op, Erase) else None
    if isinstance(op, (Recolour, Redo)):
        changed = np.abs(after["colors"] - before_obs["colors"]).max(1) > 1e-4
        assert changed.any() and not changed[~_torso(state)].any()
    if isinstance(op, PaintUnseen):
        assert not state.seen_flags()[torch.as_tensor(_torso(state))].any()
    assert s.undo() is entry and not s.entries()
    for name, arrays in (("observation", before_obs), ("canonical", before_can)):
        now = _snap_arrays(state.snapshot(name, 1 if name == "observation" else 0))
        for k in arrays:
            assert np.array_equal(now[k], arrays[k]), (name, k)
    assert torch.equal(state.seen_flags(), before_flags)
    assert s.redo() is entry and len(s.entries()) == 1
    if after is not None:
        again = _snap_arrays(state.snapshot("observation", 1))
        assert all(np.array_equal(again[k], after[k]) for k in after)


def test_erase_removes_exactly_the_selected_texels_from_snapshots_and_ply(trained, tmp_path):
    from reconstruct.ply import read_gaussians_ply, write_snapshot_ply

    state = trained.state
    full = state.snapshot("observation", 0)
    s = EditSession(state)
    s.select_part("head")
    s.apply(Erase())
    head = s.selection
    snap = state.snapshot("observation", 0)
    assert len(snap) == state.num_gaussians - head.sum()
    assert np.array_equal(snap.ids, np.flatnonzero(~head))
    assert np.array_equal(snap.means, full.means[~head]) and np.array_equal(snap.colors, full.colors[~head])
    # posed Gaussians (renders, evaluation): opacity 0 exactly there
    op = state.posed(0).opacities.detach().numpy()
    assert (op[head] == 0).all() and (op[~head] == 1).all()
    out = write_snapshot_ply(tmp_path / "a.ply", snap)
    ply = read_gaussians_ply(out)
    assert len(ply.means) == len(snap)
    # a render shows none of the erased: first hits never name them
    from reconstruct.train.render import render_avatar

    r = render_avatar(state.posed(0), trained.scene.frames[0].camera, trained.background, first_hit=True)
    hits = r.first_hit[r.first_hit >= 0].numpy()
    assert not head[hits].any()


def test_recolour_only_changes_the_hue_as_asked():
    from reconstruct.edits.colour import hsv_to_rgb, recolour, rgb_to_hsv

    rgb = torch.rand(200, 3)
    assert torch.allclose(hsv_to_rgb(rgb_to_hsv(rgb)), rgb, atol=1e-5)
    assert torch.allclose(recolour(rgb, 360.0, 1.0, 1.0), rgb, atol=1e-5)
    red = torch.tensor([[1.0, 0.0, 0.0]])
    assert torch.allclose(recolour(red, 120.0, 1.0, 1.0), torch.tensor([[0.0, 1.0, 0.0]]), atol=1e-5)
    assert torch.allclose(recolour(red, 0.0, 0.0, 0.5), torch.tensor([[0.5, 0.5, 0.5]]), atol=1e-5)


# ----- the lock under training ---------------------------------------------------------------
def test_lock_holds_through_stage1_and_stage2(trained):
    from reconstruct.stage2.plan import start_stage2

    state = trained.state
    s = EditSession(state)
    s.select_part("torso")
    locked = torch.as_tensor(s.selection)
    s.apply(Lock())
    at_lock = _decoded(state)
    for _ in range(10):
        trained.step()
    now = _decoded(state)
    for k in at_lock:
        assert float((now[k][locked] - at_lock[k][locked]).abs().max()) <= LOCK_TOL, k
    assert float((now["colors"][~locked] - at_lock["colors"][~locked]).abs().max()) > 1e-4  # the rest trained
    # Stage II (pose injection: decoding depends on the frame); a second lock made there, on the head
    start_stage2(trained, _stage2_cfg(lambda_sds=1.0, given_view_ratio=0.5), allow_incomplete=True)
    s.select_part("head")
    head = torch.as_tensor(s.selection)
    for _ in range(3):
        trained.step()
    s.apply(Lock())
    head_at = {f: _decoded(state, f) for f in (None, 0, 2)}
    for _ in range(12):
        trained.step()
    assert {"canonical", "observation"} & set(trained.kind_counts)  # guidance steps ran
    for f in (None, 0, 2):
        now = _decoded(state, f)
        for k in at_lock:  # Stage I's lock: its Stage I attributes at every frame
            assert float((now[k][locked] - at_lock[k][locked]).abs().max()) <= LOCK_TOL, (f, k)
            assert float((now[k][head] - head_at[f][k][head]).abs().max()) <= LOCK_TOL, (f, k)
    # the lock is loss-free: no gradient reaches the locked rows of a per-Gaussian parameter
    canon, _ = state.decode(0)
    canon.colors.sum().backward()
    g = state.model.decoder.color_residual.grad if hasattr(state.model.decoder, "color_residual") else None
    if g is not None:
        assert float(g[locked].abs().max()) == 0.0


# ----- painted visibility and Stage II ---------------------------------------------------------
def test_painting_changes_stage2_view_selection(trained):
    from reconstruct.stage2.plan import start_stage2

    plan = start_stage2(trained, _stage2_cfg(), allow_incomplete=True)
    state = trained.state
    base_unseen, total = plan.num_unseen, len(plan.selected_views)
    vis = {(s.frame, v.azimuth_deg, v.elevation_deg): v.visibility for s in plan.spaces for v in s.views}
    s = EditSession(state, plan=plan)
    s.select_part("body")
    s.apply(PaintUnseen())
    assert plan.num_unseen == total  # nothing seen: every candidate view is unseen
    assert not state.trusted_seen.any()
    s.undo()
    assert plan.num_unseen == base_unseen
    assert vis == {(s_.frame, v.azimuth_deg, v.elevation_deg): v.visibility for s_ in plan.spaces for v in s_.views}
    # the torso painted unseen: the front views' visible share drops
    s.select_part("torso")
    s.apply(PaintUnseen())
    front = [v for v in plan.spaces[0].views if abs(v.azimuth_deg) < 1 and abs(v.elevation_deg) < 45]
    before_front = [vis[(None, v.azimuth_deg, v.elevation_deg)] for v in front]
    assert all(v.visibility < b for v, b in zip(front, before_front))
    # the pseudo-colours follow: redo re-propagates the torso and guidance trains on
    s.undo()
    s.select_part("body")
    s.apply(PaintSeen())
    assert plan.num_unseen == 0 and plan.sds_note


def test_redo_resets_the_region_to_the_prior_appearance(trained):
    from reconstruct.stage2.plan import start_stage2

    plan = start_stage2(trained, _stage2_cfg(), allow_incomplete=True)
    state = trained.state
    s = EditSession(state, plan=plan)
    s.select_part("torso")
    torso = torch.as_tensor(s.selection)
    s.apply(Redo())
    assert not state.trusted_seen[torso].any()
    c = _decoded(state)["colors"]
    assert float((c[torso] - plan.pseudo_colors[torso]).abs().max()) < 1e-4
    for _ in range(4):  # guidance steps train the region on from there
        trained.step()


def test_a_redone_region_takes_no_mirrored_colour(trained, monkeypatch):
    """What a redo resets to is the wrap fill's low-frequency part: the plan's propagated colours
    are made with the redone Gaussians marked no_mirror (what no_mirror does to the fill:
    tests/test_propagation_wrap.py), and undo takes the mark back."""
    from reconstruct.appearance import pseudo_appearance as fill_module  # the plan's propagated colours
    from reconstruct.stage2.plan import start_stage2

    seen_args = []
    real = fill_module.wrap_fill_colors
    monkeypatch.setattr(fill_module, "wrap_fill_colors",
                        lambda *a, **kw: seen_args.append(kw.get("no_mirror")) or real(*a, **kw))
    plan = start_stage2(trained, _stage2_cfg(), allow_incomplete=True)
    assert seen_args[-1] is None
    state = trained.state
    s = EditSession(state, plan=plan)
    s.select_part("torso")
    torso = s.selection.copy()
    s.apply(Redo())
    np.testing.assert_array_equal(seen_args[-1], torso)
    s.undo()
    assert seen_args[-1] is None and state.edits.redone is None


# ----- the run folder ----------------------------------------------------------------------------
def _run_folder(trained, tmp_path):
    from reconstruct.run_folder import RunFolder

    trained.save()
    run = RunFolder(trained.run_dir)
    run.update_info({"scene": "tiny", "stage": trained.stage})
    return run


def test_edits_are_kept_in_the_run_folder_and_applied_on_resume(trained, tmp_path):
    run = _run_folder(trained, tmp_path)
    s = EditSession(trained.state, run_dir=run.path)
    s.select_part("head")
    s.apply(Erase())
    s.select_part("torso")
    s.apply(Lock())
    s.apply(Recolour(90, 1.2, 0.9))
    s.select_part("arms")
    s.apply(Redo())
    s.apply(PaintSeen())
    s.undo()
    expected = _snap_arrays(trained.state.snapshot("observation", 2))
    doc = json.loads(run.edits_path.read_text())
    assert [e["op"] for e in doc["applied"]] == ["erase", "lock", "recolour", "redo"]
    assert [e["op"] for e in doc["undone"]] == ["seen"]
    resumed = run.resume(trained.scene)
    assert len(resumed.state.edits) == 4
    got = _snap_arrays(resumed.avatar().make_snapshot("observation", 2))
    for k in expected:
        assert np.array_equal(got[k], expected[k]), k
    s2 = EditSession(resumed.state, run_dir=run.path)
    assert s2.can_redo and s2.redo().op.name == "seen"
    assert len(list(run.edits_path.parent.glob("e*.npz"))) == 5


@pytest.mark.parametrize("damage", ["json", "op", "mask", "pickle", "missing", "count"])
def test_a_bad_edits_file_is_refused_naming_it(trained, tmp_path, damage):
    from reconstruct.edits.store import load_edits

    run = _run_folder(trained, tmp_path)
    s = EditSession(trained.state, run_dir=run.path)
    s.select_part("head")
    s.apply(Erase())
    path = run.edits_path
    npz = path.parent / "e0001.npz"
    doc = json.loads(path.read_text())
    if damage == "json":
        path.write_text("{not json")
    elif damage == "op":
        doc["applied"][0]["op"] = "explode"
        path.write_text(json.dumps(doc))
    elif damage == "mask":
        np.savez(npz, mask=np.zeros(7, bool))
    elif damage == "pickle":
        np.savez(npz, mask=np.array([{"a": 1}], dtype=object))
    elif damage == "missing":
        npz.unlink()
    else:
        doc["num_gaussians"] = 5
        path.write_text(json.dumps(doc))
    files = {p: p.read_bytes() for p in run.path.rglob("*") if p.is_file() and p.name != ".lock"}
    with pytest.raises(EditsError, match=str(path).replace(".", r"\.")):
        run.resume(trained.scene)
    with pytest.raises(EditsError, match="edits.json"):
        load_edits(run.path, trained.state.num_gaussians)
    assert files == {p: p.read_bytes() for p in run.path.rglob("*") if p.is_file() and p.name != ".lock"}


def test_headless_edit_command(tmp_path, capsys):
    from app.cli import main
    from reconstruct.run_folder import RunFolder

    run = tmp_path / "run"
    train_tiny(run)
    assert main(["edit", str(run), "--select", "part=head", "--op", "erase"]) == 0
    assert main(["edit", str(run), "--select", "rect=0,0,24,48@front", "--select=-part=head", "--op",
                 "recolour:30,1,0.5", "--size", "48"]) == 0
    script = tmp_path / "s.json"
    script.write_text(json.dumps([{"select": ["part=arms"], "grow": 1, "op": "lock"},
                                  {"select": "lasso=0,0,48,0,48,48@back", "through": True, "op": "unseen"},
                                  {"undo": 1}]))
    assert main(["edit", str(run), "--script", str(script), "--size", "48"]) == 0
    out = capsys.readouterr().out
    assert "applied #1 erase" in out and "undid #4 unseen" in out
    trainer = RunFolder(run).resume()
    assert [e.op.name for e in trainer.state.edits] == ["erase", "recolour", "lock"]
    head = trainer.state.edits.entries[0].mask
    assert len(trainer.avatar().make_snapshot()) == trainer.state.num_gaussians - head.sum()
    assert main(["edit", str(run), "--list"]) == 0
    assert main(["edit", str(run), "--op", "sparkle"]) == 2
    assert main(["edit", str(run), "--select", "part=head", "--op", "recolour:1,2"]) == 2
    assert main(["edit", str(run), "--select", "rect=0,0,4,4", "--op", "erase"]) == 2  # no @VIEW
    (run / "edits" / "edits.json").write_text("[]")
    capsys.readouterr()
    assert main(["edit", str(run), "--list"]) == 2
    assert "edits.json" in capsys.readouterr().err
    # eval and export refuse it too
    assert main(["eval", str(run)]) == 2
