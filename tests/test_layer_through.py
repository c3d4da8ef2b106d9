"""The garment layer's Gaussians that show the body past its edges (reconstruct/avatar/layer_through.py)."""

import numpy as np
import pytest

from reconstruct.avatar.layer_through import ThroughConfig, colour_distance, layer_shows_body
from reconstruct.body.parts import PART_INDEX

SKIN = np.array([0.66, 0.50, 0.45])
SHIRT = np.array([0.92, 0.92, 0.90])
R, C = 24, 48
TOP, HEM = 0.0, -0.5  # the layer's top and bottom rows, metres


def _tube(radius=0.25):
    """Layer grid points on a cylinder, column 0 at the front (-y), rows from TOP down to HEM."""
    rows, cols = np.meshgrid(np.arange(R), np.arange(C), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    ang = 2 * np.pi * cols / C
    z = TOP + (HEM - TOP) * rows / (R - 1)
    pos = np.c_[radius * np.sin(ang), -radius * np.cos(ang), z]
    return pos, np.c_[rows, cols]


def _body(rng):
    """Seen front surface points of two shins under the layer (skin) and of the torso above it (a
    shirt); none hidden by the cloth."""
    pts, parts, cols = [], [], []
    for x, part in ((0.1, "shin.L"), (-0.1, "shin.R")):
        z = rng.uniform(HEM - 0.4, HEM - 0.01, 300)
        a = rng.uniform(-np.pi / 2, np.pi / 2, 300)
        pts.append(np.c_[x + 0.06 * np.sin(a), -0.06 * np.cos(a), z])
        parts += [PART_INDEX[part]] * 300
        cols.append(SKIN + rng.uniform(-0.03, 0.03, (300, 3)))
    z = rng.uniform(TOP + 0.01, TOP + 0.3, 400)
    a = rng.uniform(-np.pi / 2, np.pi / 2, 400)
    pts.append(np.c_[0.15 * np.sin(a), -0.12 * np.cos(a), z])
    parts += [PART_INDEX["torso"]] * 400
    cols.append(SHIRT + rng.uniform(-0.03, 0.03, (400, 3)))
    pts, cols = np.concatenate(pts), np.concatenate(cols)
    return pts, np.asarray(parts), cols, np.ones(len(pts), bool), np.zeros(len(pts), bool)


def _layer_colours(rng, rc, pos, cloth=np.array([0.5, 0.5, 0.5])):
    """Pleated cloth (alternating columns 0.15 lighter and darker), seen at the front; the three
    bottom rows over the legs show noisy skin and the top row over the chest the shirt."""
    col = cloth + np.where(rc[:, 1] % 2 == 0, 0.15, -0.15)[:, None] + rng.uniform(-0.02, 0.02, (len(rc), 3))
    seen = pos[:, 1] < -0.05
    legs = seen & (rc[:, 0] >= R - 3) & (np.abs(pos[:, 0]) < 0.17)
    col[legs] = SKIN + rng.uniform(-0.06, 0.06, (legs.sum(), 3))
    chest = seen & (rc[:, 0] == 0) & (np.abs(pos[:, 0]) < 0.12)
    col[chest] = SHIRT + rng.uniform(-0.03, 0.03, (chest.sum(), 3))
    return np.clip(col, 0, 1), seen, legs, chest


def _near(region, rc, h=ThroughConfig().window):
    """``region`` widened by ``h`` columns along the rows: the colour window's reach."""
    grid = np.zeros((R, C), bool)
    grid[rc[region, 0], rc[region, 1]] = True
    wide = np.zeros_like(grid)
    for d in range(-h, h + 1):
        wide |= np.roll(grid, d, axis=1)
    return wide[rc[:, 0], rc[:, 1]]


def _flags(body, pos, col, seen, rc, **kw):
    bp, bparts, bcol, bseen, bhidden = body
    return layer_shows_body(bp, bparts, bcol, bseen, bhidden, pos, col, seen, rc, (R, C), config=ThroughConfig(**kw))


def test_colour_distance_is_the_opponent_space_norm():
    a, b = np.array([0.7, 0.57, 0.51]), np.array([0.55, 0.55, 0.54])
    want = np.sqrt((0.13 - 0.0) ** 2 + (0.06 - 0.01) ** 2 + (0.5 * (a.mean() - b.mean())) ** 2)
    assert colour_distance(a, b) == pytest.approx(want, abs=1e-12)
    assert colour_distance(b, a) == pytest.approx(want, abs=1e-12)
    # a change of brightness alone counts half, one of hue in full
    assert colour_distance([0.5, 0.5, 0.5], [0.6, 0.6, 0.6]) == pytest.approx(0.05)
    assert colour_distance([0.5, 0.5, 0.5], [0.6, 0.5, 0.5]) > 0.1


def test_the_legs_under_the_hem_show_the_body_and_the_top_is_not_read():
    """Noisy skin over the legs under the hem is found; the shirt showing over the layer's top is
    not (above the top the body is mostly the same garment, a dress's bodice)."""
    rng = np.random.default_rng(0)
    pos, rc = _tube()
    col, seen, legs, chest = _layer_colours(rng, rc, pos)
    flags = _flags(_body(rng), pos, col, seen, rc)
    assert not (flags & ~_near(legs, rc)).any(), "cloth taken for the body"
    assert flags[legs].mean() > 0.9
    assert not (flags & ~seen).any()


def test_legs_that_drew_the_cloth_just_under_the_hem_are_no_reference():
    """The shins' Gaussians within 5 cm under the layer's bottom row painted the cloth's grey (they
    drew the hem's pixels): more than half the reference within 25 cm, and read from 2 cm above
    the bottom row (the settings before) no column is read; from 5 cm down the skin is found."""
    rng = np.random.default_rng(7)
    pos, rc = _tube()
    col, seen, legs, _ = _layer_colours(rng, rc, pos)
    bp, bparts, bcol, bseen, bhidden = _body(rng)
    near_hem = (bparts != PART_INDEX["torso"]) & (bp[:, 2] > HEM - 0.05)
    extra = 400  # more shin Gaussians just under the hem, all in the cloth's grey
    z = rng.uniform(HEM - 0.05, HEM - 0.005, extra)
    a = rng.uniform(-np.pi / 2, np.pi / 2, extra)
    x = np.where(np.arange(extra) % 2 == 0, 0.1, -0.1)
    bp = np.r_[bp, np.c_[x + 0.06 * np.sin(a), -0.06 * np.cos(a), z]]
    bparts = np.r_[bparts, np.full(extra, PART_INDEX["shin.L"])]
    bcol = np.r_[bcol, np.tile([0.5, 0.5, 0.5], (extra, 1))]
    bcol[np.r_[near_hem, np.zeros(extra, bool)]] = 0.5
    bseen, bhidden = np.ones(len(bp), bool), np.zeros(len(bp), bool)
    body = (bp, bparts, bcol, bseen, bhidden)
    flags = _flags(body, pos, col, seen, rc)
    assert flags[legs].mean() > 0.8 and not (flags & ~_near(legs, rc)).any()
    assert not _flags(body, pos, col, seen, rc, edge_slack=0.02, reach=0.25).any()


def test_the_walk_from_the_edge_stops_at_the_cloth():
    """Skin-coloured cloth above a cloth hem band (a print over the hem) is not the body: the walk
    from the edge stops at the first cloth in its column. The other columns still find the legs."""
    rng = np.random.default_rng(1)
    pos, rc = _tube()
    col, seen, legs, _ = _layer_colours(rng, rc, pos)
    band = legs & np.isin(rc[:, 1], [1, 2, 3, 4])
    col[band & (rc[:, 0] >= R - 2)] = 0.5  # the hem band, grey
    print_ = seen & np.isin(rc[:, 1], [1, 2, 3, 4]) & (rc[:, 0] >= R - 5) & (rc[:, 0] < R - 2)
    col[print_] = SKIN
    flags = _flags(_body(rng), pos, col, seen, rc)
    assert not flags[print_].any()
    assert flags[legs & ~_near(band, rc)].mean() > 0.9


def test_a_body_coloured_print_inside_the_cloth_stops_the_reading():
    """Cloth that shows the body's colour well inside it (a skin-toned print mid-skirt): the legs'
    colour is the cloth's too, and nothing is flagged."""
    rng = np.random.default_rng(5)
    pos, rc = _tube()
    col, seen, legs, _ = _layer_colours(rng, rc, pos)
    patch = seen & (rc[:, 0] >= 10) & (rc[:, 0] <= 13) & (np.abs(pos[:, 0]) < 0.17)
    col[patch] = SKIN
    assert not _flags(_body(rng), pos, col, seen, rc).any()


def test_an_open_front_showing_the_legs_from_the_hem_up_is_not_the_cloths_colour():
    """An open coat: the legs show between its front edges from the hem up to mid-height. Joined to
    the legs under the hem, that strip is the body, not a colour of the cloth: the legs under the
    hem are found (and the strip's bottom, within ``depth``). The same strip cut off from the hem by
    one row of cloth is a print, and nothing is flagged."""
    rng = np.random.default_rng(6)
    pos, rc = _tube()
    col, seen, legs, _ = _layer_colours(rng, rc, pos)
    strip = seen & (rc[:, 0] >= 8) & (np.abs(pos[:, 0]) < 0.07)
    col[strip] = SKIN + rng.uniform(-0.06, 0.06, (strip.sum(), 3))
    body = _body(rng)
    flags = _flags(body, pos, col, seen, rc)
    assert flags[legs].mean() > 0.9
    assert not (flags & ~_near(legs | strip, rc)).any(), "cloth taken for the body"
    assert flags[strip & (pos[:, 2] > HEM + ThroughConfig().depth + 0.01)].sum() == 0  # the walk's reach
    cut = seen & (rc[:, 0] == R - 4)
    col[cut] = 0.5 + np.where(rc[cut, 1] % 2 == 0, 0.15, -0.15)[:, None]
    assert not _flags(body, pos, col, seen, rc).any()


def test_nothing_is_told_apart_on_cloth_of_the_bodys_colour():
    """A skin-toned skirt over bare legs: the body and the cloth cannot be told apart, nothing is flagged."""
    rng = np.random.default_rng(2)
    pos, rc = _tube()
    col, seen, _, _ = _layer_colours(rng, rc, pos, cloth=SKIN)
    col = SKIN + rng.uniform(-0.05, 0.05, col.shape)
    assert not _flags(_body(rng), pos, col, seen, rc).any()


def test_more_than_the_share_flagged_is_taken_for_cloth():
    rng = np.random.default_rng(3)
    pos, rc = _tube()
    col, seen, _, _ = _layer_colours(rng, rc, pos)
    body = _body(rng)
    flags = _flags(body, pos, col, seen, rc)
    share = flags.sum() / seen.sum()
    assert 0 < share < 0.5
    assert not _flags(body, pos, col, seen, rc, max_share=share * 0.9).any()


def test_no_reference_within_reach_flags_nothing():
    rng = np.random.default_rng(4)
    pos, rc = _tube()
    col, seen, legs, _ = _layer_colours(rng, rc, pos)
    bp, bparts, bcol, bseen, bhidden = _body(rng)
    far = bp + np.array([0.0, 0.0, -5.0]) * (bparts != PART_INDEX["torso"])[:, None]
    assert _flags((bp, bparts, bcol, bseen, bhidden), pos, col, seen, rc)[legs].any()
    assert not _flags((far, bparts, bcol, bseen, bhidden), pos, col, seen, rc).any()
    # the body the cloth hides is no reference either
    hidden = bparts != PART_INDEX["torso"]
    assert not _flags((bp, bparts, bcol, bseen, hidden), pos, col, seen, rc).any()


# ---- arms and hands in front of the layer (``layer_shows_limbs``) ----

CLOTH = np.array([0.09, 0.16, 0.28])
SLEEVE = np.array([0.70, 0.74, 0.83])


def _limb_scene(rng, arm_rows=range(0, 10), sleeve_cloth=False):
    """A front-view camera, the tube (seen on its front half), and an arm hanging beside it at the
    tube's left front edge (x = 0.22 m), its seen Gaussians in a sleeve's colour. The photo drew the
    arm over the layer Gaussians the arm covers in the image, in ``arm_rows``: they took the
    sleeve's colour; the rest of the seen layer is the cloth (with noise)."""
    from reconstruct.camera import Camera

    cam = Camera.look_at((0.0, -3.0, -0.25), (0.0, 0.0, -0.25), width=256, height=256, fov_y_deg=30)
    pos, rc = _tube()
    seen = pos[:, 1] < -0.05
    cloth = SLEEVE if sleeve_cloth else CLOTH
    col = cloth + rng.uniform(-0.03, 0.03, (len(pos), 3))
    z = rng.uniform(-0.30, 0.0, 400)
    arm = np.c_[0.22 + rng.uniform(-0.03, 0.03, 400), -0.30 + rng.uniform(-0.03, 0.03, 400), z]
    uv_arm, _ = cam.project(arm)
    uv, depth = cam.project(pos)
    dist = np.min(np.linalg.norm(uv[:, None] - uv_arm[None], axis=2), 1) * depth / cam.fx  # metres in the image
    painted = seen & (dist < 0.02) & np.isin(rc[:, 0], list(arm_rows))
    col[painted] = SLEEVE + rng.uniform(-0.03, 0.03, (painted.sum(), 3))
    parts = np.full(len(arm), PART_INDEX["lowerarm.L"])
    arm_col = SLEEVE + rng.uniform(-0.03, 0.03, (len(arm), 3))
    return cam, pos, rc, seen, col, arm, parts, arm_col, painted


def _limbs(cam, pos, rc, seen, col, arm, parts, arm_col, **kw):
    from reconstruct.avatar.layer_through import LimbConfig, layer_shows_limbs

    return layer_shows_limbs([(cam, arm, pos)], parts, arm_col, np.ones(len(arm), bool), col, seen, rc, (R, C),
                             config=LimbConfig(**kw))


def test_layer_gaussians_painted_like_an_arm_in_front_of_them_are_found():
    rng = np.random.default_rng(0)
    cam, pos, rc, seen, col, arm, parts, arm_col, painted = _limb_scene(rng)
    assert painted.sum() >= 8
    out = _limbs(cam, pos, rc, seen, col, arm, parts, arm_col)
    assert out[painted].mean() > 0.9
    assert not out[~painted].any()  # the cloth round the arm, and below it, is not marked


def test_the_sleeves_colour_away_from_the_arm_is_cloth():
    """A small light print on the cloth far from the arm in the image stays a colour source (a large
    one, the cloth in the arm's colour, stops the rule: next test)."""
    rng = np.random.default_rng(1)
    cam, pos, rc, seen, col, arm, parts, arm_col, painted = _limb_scene(rng)
    uv, depth = cam.project(pos)
    uv_arm, _ = cam.project(arm)
    far = seen & (np.min(np.linalg.norm(uv[:, None] - uv_arm[None], axis=2), 1) * depth / cam.fx > 0.12)
    print_ = np.flatnonzero(far & (rc[:, 0] < 6) & (np.abs(pos[:, 0]) < 0.08))[:6]  # a small light print
    assert len(print_) == 6
    col[print_] = SLEEVE
    out = _limbs(cam, pos, rc, seen, col, arm, parts, arm_col)
    assert not out[print_].any() and out[painted].mean() > 0.9


@pytest.mark.parametrize("rule", ["limbs", "behind"])
def test_no_limb_marks_when_the_cloth_is_the_sleeves_colour_or_too_many_or_out_of_reach(rule):
    """Both arm rules (``layer_shows_limbs``, ``layer_behind_limbs``): cloth in the sleeve's colour
    cannot be told from the arm; more than ``max_share`` of the seen layer flagged is taken for
    cloth; an arm far to the side in the image flags nothing."""
    rng = np.random.default_rng(2)
    cam, pos, rc, seen, col, arm, parts, arm_col, _ = _limb_scene(rng, sleeve_cloth=True)
    flags = _limbs if rule == "limbs" else _behind
    assert not flags(cam, pos, rc, seen, col, arm, parts, arm_col).any()
    cam, pos, rc, seen, col, arm, parts, arm_col, painted = _limb_scene(rng)
    assert flags(cam, pos, rc, seen, col, arm, parts, arm_col).any()
    share = painted.sum() / seen.sum()
    assert not flags(cam, pos, rc, seen, col, arm, parts, arm_col, max_share=0.5 * share).any()
    assert not flags(cam, pos, rc, seen, col, arm + [0.5, 0, 0], parts, arm_col).any()


# ---- arms and hands in front of the layer, the layer behind them (``layer_behind_limbs``) ----


def _behind(cam, pos, rc, seen, col, arm, parts, arm_col, **kw):
    from reconstruct.avatar.layer_through import BehindConfig, layer_behind_limbs

    return layer_behind_limbs([(cam, arm, pos)], parts, arm_col, np.ones(len(arm), bool), col, seen, rc,
                              BehindConfig(**kw))


def test_layer_gaussians_behind_an_arm_in_its_colour_are_found_and_nothing_else():
    """The arm hangs 18 cm in front of the tube's edge: the layer Gaussians painted like it are
    behind it, and found; the cloth-coloured ones within reach of it, and the rest, are not."""
    rng = np.random.default_rng(3)
    cam, pos, rc, seen, col, arm, parts, arm_col, painted = _limb_scene(rng)
    uv, depth = cam.project(pos)
    uv_arm, depth_arm = cam.project(arm)
    d = np.linalg.norm(uv[:, None] - uv_arm[None], axis=2)
    nearest = d.argmin(1)
    reach = seen & (d.min(1) * depth / cam.fx <= 0.03)
    assert (depth - depth_arm[nearest])[painted].min() > 0.1  # behind it
    assert (reach & ~painted).sum() >= 8  # cloth within reach that must stay
    out = _behind(cam, pos, rc, seen, col, arm, parts, arm_col)
    assert out[painted].mean() > 0.9
    assert not out[~painted].any()


def test_the_layer_in_front_of_an_arm_or_out_of_reach_is_not_behind_it():
    rng = np.random.default_rng(4)
    cam, pos, rc, seen, col, arm, parts, arm_col, painted = _limb_scene(rng)
    assert painted.sum() >= 8
    # the same arm behind the tube's front (inside the skirt, the layer nearer the camera)
    inside = arm + [0.0, 0.45, 0.0]
    assert not _behind(cam, pos, rc, seen, col, inside, parts, arm_col).any()
    # within the depth gap: not behind either
    uv, depth = cam.project(pos)
    gap = float((depth[painted] - cam.project(arm)[1].mean()).max()) + 0.05
    assert not _behind(cam, pos, rc, seen, col, arm, parts, arm_col, depth_gap=gap).any()
    # unseen layer Gaussians are never flagged
    assert not _behind(cam, pos, rc, seen & ~painted, col, arm, parts, arm_col)[painted].any()


def test_median_colour_within_matches_a_direct_search():
    """``median_colour_within`` against a brute-force search: per destination, the first view in
    which at least k sources lie within reach (metres at the destination's depth) in the image, and
    the median of their colours; NaN where no view has k."""
    from reconstruct.avatar.layer_through import median_colour_within
    from reconstruct.camera import Camera

    rng = np.random.default_rng(7)
    cams = [Camera.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), width=128, height=128, fov_y_deg=30),
            Camera.look_at((3.0, 0.0, 0.0), (0.0, 0.0, 0.0), width=128, height=128, fov_y_deg=30)]
    body, layer = rng.uniform(-0.3, 0.3, (60, 3)), rng.uniform(-0.3, 0.3, (200, 3))
    colours = rng.uniform(0, 1, (200, 3))
    src, dst = np.arange(0, 200, 2), np.arange(60)
    views = [(cam, body, layer) for cam in cams]
    reach, k = 0.05, 3
    got = median_colour_within(views, (2, src), colours[src], (1, dst), reach, k)
    want = np.full((len(dst), 3), np.nan)
    for j, d in enumerate(dst):
        for cam in cams:
            duv, dz = cam.project(body[d:d + 1])
            suv, _ = cam.project(layer[src])
            near = np.linalg.norm(suv - duv, axis=1) <= reach * cam.fx / dz[0]
            if near.sum() >= k:
                want[j] = np.median(colours[src][near], axis=0)
                break
    assert np.isfinite(want[:, 0]).sum() >= 10 and np.isnan(want[:, 0]).sum() >= 5
    assert np.allclose(got, want, equal_nan=True)
