"""The garment layer's front and back moved to the depth of its sides at the end of Stage I
(reconstruct.avatar.layer_depth): the per-row pulls against a brute-force reference, the move
(front and back only, in depth only, once), its record in checkpoints, and the finish's switch."""

import dataclasses

import numpy as np
import pytest
import torch

from reconstruct.avatar.garment_layer import GarmentLayer, VolumeHint, build_garment_layer, landmark_heights
from reconstruct.avatar.layer_depth import FACING, MIN_PER_ROW, depth_pulls, match_layer_depth


def _ring(rows: int, cols: int):
    theta = np.arange(cols) * 2 * np.pi / cols
    n = np.stack([np.sin(theta), -np.cos(theta), np.zeros(cols)], 1)  # theta 0: the front (-Y)
    return np.tile(n, (rows, 1)), np.repeat(np.arange(rows), cols)


def _reference(off, n, rows, opaque, R):
    """float64 brute force: per row, median over front/back minus median over sides, unsmoothed."""
    out = np.full(R, np.nan)
    for r in range(R):
        fb = [o for o, nn, rr, op in zip(off, n, rows, opaque) if rr == r and op and abs(nn[1]) > FACING]
        sd = [o for o, nn, rr, op in zip(off, n, rows, opaque) if rr == r and op and abs(nn[0]) > FACING]
        if len(fb) >= MIN_PER_ROW and len(sd) >= MIN_PER_ROW:
            out[r] = float(np.median(fb)) - float(np.median(sd))
    return out


def test_pulls_are_the_sides_offset_against_the_front_and_back():
    rng = np.random.default_rng(0)
    R, C = 9, 24
    n, rows = _ring(R, C)
    off = rng.normal(0, 0.0005, len(rows))
    sides = np.abs(n[:, 0]) > FACING
    off[sides] -= 0.004 + 0.0005 * rows[sides]  # the sides pulled in 4 mm at the top, 8 mm at the hem
    opaque = np.ones(len(rows), bool)
    want = _reference(off, n, rows, opaque, R)
    got = depth_pulls(off, n, rows, opaque, R, smooth_rows=1)
    np.testing.assert_allclose(got, np.clip(want, 0, 0.01), atol=1e-12)
    assert 0.003 < got[0] < 0.005 and 0.007 < got[-1] < 0.009
    # a turned video pulled the front and back in as well: nothing to move
    turned = off.copy()
    fb = np.abs(n[:, 1]) > FACING
    for r in range(R):
        turned[fb & (rows == r)] = np.median(off[sides & (rows == r)])
    assert depth_pulls(turned, n, rows, opaque, R, smooth_rows=1).max() < 1e-12
    # clipped to max_pull; a row pushed out at the sides (negative) gives 0
    assert depth_pulls(off * 5, n, rows, opaque, R, smooth_rows=1, max_pull=0.01).max() == pytest.approx(0.01)
    assert depth_pulls(-off, n, rows, opaque, R, smooth_rows=1).max() == 0.0


def test_rows_without_evidence_take_their_neighbours_and_spikes_are_smoothed():
    R, C = 7, 24
    n, rows = _ring(R, C)
    sides = np.abs(n[:, 0]) > FACING
    off = np.where(sides, -0.004, 0.0)
    opaque = np.ones(len(rows), bool)
    opaque[(rows == 3) & sides] = False  # row 3: no opaque side Gaussian (the hem cut away, say)
    got = depth_pulls(off, n, rows, opaque, R, smooth_rows=1)
    np.testing.assert_allclose(got, 0.004, atol=1e-12)
    spike = off.copy()
    spike[(rows == 5) & sides] = -0.009
    assert depth_pulls(spike, n, rows, np.ones(len(rows), bool), R, smooth_rows=1)[5] == pytest.approx(0.009)
    assert depth_pulls(spike, n, rows, np.ones(len(rows), bool), R, smooth_rows=5)[5] == pytest.approx(0.004)
    assert not depth_pulls(off, n, rows, np.zeros(len(rows), bool), R).any()  # nothing opaque: no move


@pytest.fixture(scope="module")
def body(tiny_scene):
    return tiny_scene.body_model()


def _model_on(body, layer):
    from reconstruct.avatar import AvatarConfig, AvatarModel

    cfg = AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                       hidden=32)
    torch.manual_seed(0)
    return AvatarModel(body, cfg, layer=layer)


def _model(body):
    m = landmark_heights(body)
    return _model_on(body, build_garment_layer(
        body, VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05), cols=24, row_step=0.06))


def test_the_move_is_in_depth_at_front_and_back_only_and_once(body, monkeypatch):
    model = _model(body)
    nb = model.num_body
    with torch.no_grad():
        model.layer_opacity.fill_(5.0)  # all opaque
    n = model.base_normals[nb:].clone()
    sides = n[:, 0].abs() > FACING
    real = type(model).canonical

    def canonical(self, pose_features=None, index=None):  # the sides decoded 4 mm inside the built surface
        c = real(self, pose_features, index)
        means = c.means.clone()
        means[nb:] = self.base_positions[nb:] - 0.004 * sides[:, None].float() * n
        return dataclasses.replace(c, means=means)

    monkeypatch.setattr(type(model), "canonical", canonical)
    before = model.base_positions.clone()
    match = match_layer_depth(model)
    moved = model.base_positions - before
    assert torch.equal(moved[:nb], torch.zeros_like(moved[:nb])), "the body does not move"
    assert moved[nb:, [0, 2]].abs().max() == 0.0, "only in depth"
    # inward: the front (normal -Y) moves to +Y, the back to -Y, by the pull times |n_y|
    np.testing.assert_allclose(moved[nb:, 1].numpy(), -(match.pulls[model.layer_rc[:, 0].numpy()] * n[:, 1].numpy()),
                               atol=1e-7)
    np.testing.assert_allclose(match.shift, moved[nb:, 1].abs().numpy(), atol=1e-7)
    front, back = n[:, 1] < -0.95, n[:, 1] > 0.95
    assert float(moved[nb:][front, 1].min()) > 0.0035 and float(moved[nb:][back, 1].max()) < -0.0035
    assert float(moved[nb:][n[:, 0].abs() > 0.95, 1].abs().max()) < 0.0015
    assert torch.allclose(model.layer.positions, model.base_positions[nb:])
    assert "moved in" in match.describe()
    # what the model derives from the layer's points is as a model built on the moved layer has it
    fresh = _model_on(body, model.layer)
    assert torch.allclose(model.texel_steps, fresh.texel_steps, atol=1e-7)
    assert torch.allclose(model.layer_rest, fresh.layer_rest, atol=1e-7)
    assert not torch.allclose(model.layer_rest, _model(body).layer_rest, atol=1e-5), "the move must change them"
    assert not torch.allclose(model.texel_steps, _model(body).texel_steps, atol=1e-5)
    # a second finish on a finished avatar moves nothing more
    again = model.base_positions.clone()
    second = match_layer_depth(model)
    assert torch.allclose(model.base_positions, again, atol=1e-7)
    assert second.shift.max() < 1e-6 and "already" in second.describe()
    np.testing.assert_allclose(second.pulls, match.pulls, atol=1e-9)
    # the move travels with the layer's record
    state = model.layer.to_state()
    back_again = GarmentLayer.from_state(state)
    assert torch.equal(back_again.depth_shift, model.layer.depth_shift)
    assert torch.equal(back_again.positions, model.layer.positions)
    del state["depth_shift"]
    assert GarmentLayer.from_state(state).depth_shift is None
    state["depth_shift"] = torch.zeros(3)
    with pytest.raises(ValueError, match="depth_shift must be a float tensor of shape"):
        GarmentLayer.from_state(state, source="run/checkpoint.pt")


def test_without_a_layer_nothing_happens(body):
    from reconstruct.avatar import AvatarConfig, AvatarModel

    model = AvatarModel(body, AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8,
                                           pose_feature_channels=8, hidden=32))
    assert match_layer_depth(model) is None


def test_finish_switch_defaults_and_old_records(tiny_scene, tiny_config, body):
    from reconstruct.train.config import Stage1Config
    from reconstruct.train.trainer import Trainer

    assert Stage1Config().layer_depth_match and not Stage1Config.paper().layer_depth_match
    old = Stage1Config().to_dict()
    del old["layer_depth_match"]
    assert not Stage1Config.from_dict(old).layer_depth_match
    m = landmark_heights(body)
    layer = build_garment_layer(body, VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05),
                                cols=16, row_step=0.06)
    shifts = {}
    for on in (False, True):
        t = Trainer(tiny_scene, dataclasses.replace(tiny_config, layer_depth_match=on), None, garment_layer=layer)
        for _ in range(2):
            t.step()
        note = t.plan.finish(t)
        shifts[on] = t.model.layer.depth_shift
        assert ("garment layer: front and back" in (note or "")) == on
    assert shifts[False] is None and shifts[True] is not None and shifts[True].shape == (layer.num_gaussians,)
