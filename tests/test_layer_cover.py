"""The body under a garment layer's cloth (reconstruct.avatar.layer_cover): which body Gaussians the
cloth hides, against a brute-force float64 reference on a hand-built tube with a curved hem; the
model-level indices; and the wrap fill painting the hidden unseen ones with the cloth's colour."""

import numpy as np
import pytest
import torch

from reconstruct.appearance.wrap_fill import wrap_fill_colors
from reconstruct.avatar.garment_layer import GARMENT_PART
from reconstruct.avatar.layer_cover import body_under_layer, model_body_under_layer
from reconstruct.body.parts import PART_INDEX

R, C = 12, 24
ROW_STEP = 0.04


def _tube(radius=0.2):
    """A layer grid: rows down from z = 0, columns round; outward normals; (M,2) row/column."""
    r, c = np.meshgrid(np.arange(R), np.arange(C), indexing="ij")
    th = 2 * np.pi * c.ravel() / C
    pos = np.c_[radius * np.cos(th), radius * np.sin(th), -ROW_STEP * r.ravel()]
    nrm = np.c_[np.cos(th), np.sin(th), np.zeros(R * C)]
    return pos, nrm, np.c_[r.ravel(), c.ravel()]


def _opacity(rc):
    op = np.full(len(rc), 0.9)
    op[rc[:, 0] == 0] = 0.2  # the top fades into the body
    op[(rc[:, 1] < 6) & (rc[:, 0] >= 6)] = 0.05  # a shorter hem on one side
    op[(rc[:, 1] == 10) & (rc[:, 0] == 3)] = 0.05  # a speck: the column's run goes on under it
    op[(rc[:, 1] == 14) & (rc[:, 0] >= 4) & (rc[:, 0] <= 6)] = 0.05  # a hole of 3 rows: the hem is above it
    op[rc[:, 0] == R - 1] = 0.05
    return op


def _reference(body, parts, lpos, lnrm, rc, op, covered, margin, cut=None, bridge=2):
    """float64, brute force, loops: the nearest layer Gaussian; its column's opaque run from row 1
    across gaps of up to ``bridge`` rows (a ``cut`` Gaussian counts as opaque in a row where at
    least half the columns are)."""
    out = np.full(len(body), -1)
    hem = {}
    for col in range(C):
        z = None
        gap = 0
        for row in range(1, R):
            k = np.flatnonzero((rc[:, 0] == row) & (rc[:, 1] == col))[0]
            in_row = rc[:, 0] == row
            cloth = op[k] >= 0.5 or (cut is not None and cut[k]
                                     and (op[in_row] >= 0.5).sum() >= 0.5 * in_row.sum())
            if cloth:
                z, gap = (row, lpos[k, 2]), 0
            else:
                gap += 1
                if gap > bridge:
                    break
        hem[col] = z
    for i, p in enumerate(body):
        if parts[i] not in covered:
            continue
        j = int(np.argmin(((lpos - p) ** 2).sum(1)))
        row, col = rc[j]
        if np.dot(p - lpos[j], lnrm[j]) >= 0:
            continue
        if row == 0 and p[2] < lpos[j, 2]:  # below the top row's height: the row under it hides it
            j = int(np.flatnonzero((rc[:, 0] == 1) & (rc[:, 1] == col))[0])
            row = 1
        if hem[col] is None or row == 0 or row > hem[col][0]:
            continue
        if p[2] < hem[col][1] + margin:
            continue
        out[i] = j
    return out


def test_hidden_body_matches_brute_force():
    lpos, lnrm, rc = _tube()
    op = _opacity(rc)
    rng = np.random.default_rng(0)
    n = 3000
    th = rng.uniform(0, 2 * np.pi, n)
    rad = rng.uniform(0.05, 0.26, n)  # inside and outside the tube
    body = np.c_[rad * np.cos(th), rad * np.sin(th), rng.uniform(-0.6, 0.1, n)]
    names = ["thigh.L", "torso", "head", "upperarm.L"]
    parts = np.array([PART_INDEX[names[k]] for k in rng.integers(0, 4, n)])
    got = body_under_layer(body, parts, lpos, lnrm, rc, (R, C), op, hem_margin=0.03)
    covered = {PART_INDEX["thigh.L"], PART_INDEX["torso"]}
    want = _reference(body, parts, lpos, lnrm, rc, op, covered, 0.03)
    np.testing.assert_array_equal(got, want)
    # no bridging: the speck ends column 10's run as the hole ends column 14's
    strict = body_under_layer(body, parts, lpos, lnrm, rc, (R, C), op, hem_margin=0.03, bridge_rows=0)
    np.testing.assert_array_equal(strict, _reference(body, parts, lpos, lnrm, rc, op, covered, 0.03, bridge=0))
    col_of = rc[((lpos[None] - body[:, None]) ** 2).sum(2).argmin(1), 1]
    low = (body[:, 2] < -0.2) & (rad < 0.19) & np.isin(parts, list(covered))
    for col, bridged in ((10, True), (14, False)):
        sel = low & (col_of == col)
        assert sel.sum() > 3
        assert (got[sel] >= 0).any() == bridged and not (strict[sel] >= 0).any()
    hidden = got >= 0
    # the case is rich: many hidden, and each reason to be left out occurs
    assert 300 < hidden.sum() < n // 2
    assert not hidden[~np.isin(parts, list(covered))].any()
    assert not hidden[rad > 0.21].any()  # outside the cloth
    short = (np.mod(th, 2 * np.pi) < 2 * np.pi * 5.5 / C) & (body[:, 2] < -0.2) & (rad < 0.19)
    assert short.any() and not hidden[short & np.isin(parts, list(covered))].any()  # under the shorter hem
    assert hidden[(body[:, 2] < -0.3) & (rad < 0.19)].any()  # the longer hem hides lower
    # nearest to the top row: hidden (by row 1) below its height, not above it
    top_nearest = rc[((lpos[None] - body[:, None]) ** 2).sum(2).argmin(1), 0] == 0
    assert (hidden & top_nearest).sum() > 10 and (rc[got[hidden & top_nearest], 0] == 1).all()
    assert not hidden[top_nearest & (body[:, 2] > 0)].any()


def test_a_side_the_outline_cut_still_hides_the_body():
    """Columns 12-15 emptied by training from row 1 down: without ``cut`` they hide nothing; cut,
    they hide the body above the hem of the columns beside them. Cut Gaussians in the bottom row
    (no row there is opaque) do not lengthen the hem; an emptied column not cut (an open front over
    the person) still hides nothing. Against the brute-force reference."""
    lpos, lnrm, rc = _tube()
    op = _opacity(rc)
    side = (rc[:, 1] >= 12) & (rc[:, 1] <= 15) & (rc[:, 0] >= 1)
    op[side] = 0.02
    op[(rc[:, 1] == 18) & (rc[:, 0] >= 1)] = 0.02  # an open front: emptied, over the person's mask
    cut = side.copy()
    cut[rc[:, 0] == R - 1] = True  # below the hem: off the mask, but no garment row
    rng = np.random.default_rng(3)
    n = 3000
    th = rng.uniform(0, 2 * np.pi, n)
    rad = rng.uniform(0.05, 0.26, n)
    body = np.c_[rad * np.cos(th), rad * np.sin(th), rng.uniform(-0.6, 0.1, n)]
    parts = np.full(n, PART_INDEX["thigh.L"])
    covered = {PART_INDEX["thigh.L"]}
    before = body_under_layer(body, parts, lpos, lnrm, rc, (R, C), op, hem_margin=0.03)
    got = body_under_layer(body, parts, lpos, lnrm, rc, (R, C), op, hem_margin=0.03, cut=cut)
    np.testing.assert_array_equal(before, _reference(body, parts, lpos, lnrm, rc, op, covered, 0.03))
    np.testing.assert_array_equal(got, _reference(body, parts, lpos, lnrm, rc, op, covered, 0.03, cut=cut))
    col_of = rc[((lpos[None] - body[:, None]) ** 2).sum(2).argmin(1), 1]
    under_side = np.isin(col_of, [12, 13, 14, 15]) & (rad < 0.19) & (body[:, 2] < -0.05) & (body[:, 2] > -0.3)
    assert under_side.sum() > 30
    assert (before[under_side] == -1).all() and (got[under_side] >= 0).all()
    assert (got[col_of == 18] == -1).all()  # the open front
    # the hem is the neighbours': nothing hidden within the margin of the run's last row, nor under it
    last = lpos[(rc[:, 0] == R - 2) & (rc[:, 1] == 12), 2][0]
    assert not (got[np.isin(col_of, [12, 13, 14, 15]) & (body[:, 2] < last + 0.03)] >= 0).any()
    np.testing.assert_array_equal(got[~np.isin(col_of, [12, 13, 14, 15])], before[~np.isin(col_of, [12, 13, 14, 15])])


def test_no_layer_hides_nothing():
    lpos, lnrm, rc = _tube()
    body = np.zeros((5, 3))
    parts = np.full(5, PART_INDEX["torso"])
    out = body_under_layer(body, parts, lpos[:0], lnrm[:0], rc[:0], (0, 0), np.zeros(0))
    np.testing.assert_array_equal(out, -np.ones(5))


def test_model_indices(tiny_scene):
    from reconstruct.avatar import AvatarConfig, AvatarModel
    from reconstruct.avatar.garment_layer import VolumeHint, build_garment_layer, landmark_heights
    from reconstruct.avatar.layer_clearance import COVERED_PARTS

    body = tiny_scene.body_model()
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)
    layer = build_garment_layer(body, hint, cols=16, row_step=0.06)
    cfg = AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                       hidden=32)
    torch.manual_seed(0)
    model = AvatarModel(body, cfg, layer=layer)
    with torch.no_grad():  # opaque cloth
        model.layer_opacity.fill_(10.0)
    u = model_body_under_layer(model)
    N = model.num_body
    assert u.shape == (model.num_gaussians,) and (u[N:] == -1).all()
    hidden = u >= 0
    assert hidden.sum() > 50 and (u[hidden] >= N).all()
    covered = [PART_INDEX[p] for p in COVERED_PARTS]
    assert np.isin(model.parts()[hidden], covered).all()
    # the thighs under a knee-length layer are hidden, the shins' lower ends are not
    z = model.base_positions[:N, 2].numpy()
    thighs = np.isin(model.parts()[:N], [PART_INDEX["thigh.L"], PART_INDEX["thigh.R"]])
    assert hidden[:N][thighs & (z > m["knee"] + 0.2)].mean() > 0.8
    assert not hidden[:N][z < m["knee"]].any()
    with torch.no_grad():  # emptied cloth hides nothing
        model.layer_opacity.fill_(-10.0)
    assert (model_body_under_layer(model) == -1).all()
    assert model_body_under_layer(AvatarModel(body, cfg)) is None


def test_wrap_fill_paints_hidden_unseen_body_with_the_cloth():
    lpos, lnrm, rc = _tube()
    n_body = 40
    rng = np.random.default_rng(1)
    body = np.c_[rng.uniform(-0.1, 0.1, (n_body, 2)), rng.uniform(-0.3, -0.1, n_body)]
    pos = np.r_[body, lpos]
    parts = np.r_[np.full(n_body, PART_INDEX["torso"]), np.full(len(lpos), GARMENT_PART)]
    colors = np.r_[np.tile([0.1, 0.1, 0.1], (n_body, 1)), np.tile([0.2, 0.6, 0.2], (len(lpos), 1))]
    seen = np.ones(len(pos), bool)
    seen[:30] = False  # 30 unseen body Gaussians; 10 seen ones
    seen[n_body + 5] = False  # and an unseen layer Gaussian
    under = np.full(len(pos), -1)
    under[:n_body] = n_body + np.arange(n_body) % len(lpos)
    under[:3] = -1  # not hidden
    out = wrap_fill_colors(pos, parts, seen, colors, None, under_layer=under).numpy()
    plain = wrap_fill_colors(pos, parts, seen, colors, None).numpy()
    np.testing.assert_allclose(out[3:30], np.tile([0.2, 0.6, 0.2], (27, 1)), atol=1e-6)
    np.testing.assert_array_equal(out[:3], plain[:3])
    np.testing.assert_array_equal(out[30:], plain[30:])  # seen body and the layer as before
    assert np.abs(plain[3:30] - [0.2, 0.6, 0.2]).max() > 0.3  # without it the body keeps its own colour
    with pytest.raises(ValueError, match="under_layer must have shape"):
        wrap_fill_colors(pos, parts, seen, colors, None, under_layer=under[:-1])
