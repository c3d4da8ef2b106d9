"""Arm and hand Gaussians that drew the garment layer's cloth (reconstruct/avatar/limbs_over_cloth.py)."""

import numpy as np
import pytest

from reconstruct.avatar.limbs_over_cloth import OverClothConfig, limbs_over_cloth
from reconstruct.body.parts import PART_INDEX

SKIN = np.array([0.80, 0.62, 0.55])
CLOTH = np.array([0.45, 0.45, 0.46])
R, C = 36, 112  # rows and columns about 1.4 cm apart, as the layer's


def _scene(rng, cloth=CLOTH, hand_x=(0.10, 0.45), low=-0.25, sleeve=SKIN, forearm=200):
    """A front camera, a skirt-like tube (radius 0.25 m, seen on its front half, in ``cloth``), and
    a hand 10 cm in front of it whose left part (x < 0.2 m) lies over the tube in the image, the
    rest beside it. The photo drew the cloth where the fitted hand covers it low down (z < -0.25):
    those hand Gaussians took the cloth's colour, the rest are skin; a forearm above, beside the
    tube, is skin too. (``low``: the height below which it drew the cloth; ``sleeve``: the forearm's
    colour, ``forearm`` its Gaussians.)"""
    from reconstruct.camera import Camera

    cam = Camera.look_at((0.0, -3.0, -0.25), (0.0, 0.0, -0.25), width=256, height=256, fov_y_deg=30)
    rows, cols = np.meshgrid(np.arange(R), np.arange(C), indexing="ij")
    ang = 2 * np.pi * cols.ravel() / C
    lpos = np.c_[0.25 * np.sin(ang), -0.25 * np.cos(ang), -0.5 * rows.ravel() / (R - 1)]
    lseen = lpos[:, 1] < -0.05
    lcol = np.clip(cloth + rng.uniform(-0.03, 0.03, (len(lpos), 3)), 0, 1)
    n = 600
    hand = np.c_[rng.uniform(*hand_x, n), np.full(n, -0.35), rng.uniform(-0.40, -0.10, n)]
    fore = np.c_[rng.uniform(0.30, 0.40, forearm), np.full(forearm, -0.30), rng.uniform(0.0, 0.3, forearm)]
    pos = np.r_[hand, fore]
    parts = np.r_[np.full(n, PART_INDEX["hand.L"]), np.full(forearm, PART_INDEX["lowerarm.L"])]
    base = np.r_[np.tile(SKIN, (n, 1)), np.tile(sleeve, (forearm, 1))]
    col = np.clip(base + rng.uniform(-0.04, 0.04, (len(pos), 3)), 0, 1)
    painted = np.zeros(len(pos), bool)
    painted[:n] = (hand[:, 0] < 0.18) & (hand[:, 2] < low)
    col[painted] = np.clip(cloth + rng.uniform(-0.04, 0.04, (painted.sum(), 3)), 0, 1)
    return cam, pos, parts, col, lpos, lcol, lseen, painted


def _flags(cam, pos, parts, col, lpos, lcol, lseen, seen=None, opacity=None, **kw):
    seen = np.ones(len(pos), bool) if seen is None else seen
    return limbs_over_cloth([(cam, pos, lpos)], parts, col, seen, lcol, lseen, opacity, OverClothConfig(**kw))


def test_hand_gaussians_in_the_cloths_colour_over_it_are_found_and_nothing_else():
    rng = np.random.default_rng(0)
    cam, pos, parts, col, lpos, lcol, lseen, painted = _scene(rng)
    uv, z = cam.project(pos)
    luv, lz = cam.project(lpos)
    over = np.array([np.sum(np.linalg.norm(luv[lseen] - p, axis=1) <= 0.03 * cam.fx / d) >= 4 for p, d in zip(uv, z)])
    assert painted.sum() >= 40 and (over & ~painted).sum() >= 40  # skin over the cloth that must stay
    out = _flags(cam, pos, parts, col, lpos, lcol, lseen)
    assert out[painted].mean() > 0.9
    assert not out[~painted].any()


def test_the_limbs_own_colour_falls_back_to_the_whole_arm():
    """A hand wholly over the cloth: its own colour is the forearm's (beside the tube)."""
    rng = np.random.default_rng(1)
    cam, pos, parts, col, lpos, lcol, lseen, painted = _scene(rng, hand_x=(0.0, 0.17), low=-0.33)
    out = _flags(cam, pos, parts, col, lpos, lcol, lseen)
    assert out[painted].mean() > 0.9 and not out[~painted].any()
    # without a forearm there is no own colour: nothing
    keep = parts == PART_INDEX["hand.L"]
    assert not _flags(cam, pos[keep], parts[keep], col[keep], lpos, lcol, lseen).any()


def test_nothing_is_flagged_for_a_sleeve_of_the_cloths_colour_too_many_away_unseen_or_sheer():
    rng = np.random.default_rng(2)
    cam, pos, parts, col, lpos, lcol, lseen, painted = _scene(rng)
    assert _flags(cam, pos, parts, col, lpos, lcol, lseen).any()
    # a sleeve and a glove of the cloth's colour: the limb cannot be told from the cloth
    sleeve = np.clip(CLOTH + 0.02 + rng.uniform(-0.04, 0.04, col.shape), 0, 1)
    assert not _flags(cam, pos, parts, sleeve, lpos, lcol, lseen).any()
    # more than max_share of the seen arm flagged
    assert not _flags(cam, pos, parts, col, lpos, lcol, lseen, max_share=0.5 * painted.mean()).any()
    # the arm moved away from the cloth in the image
    assert not _flags(cam, pos + [0.6, 0, 0], parts, col, lpos, lcol, lseen).any()
    # unseen arm Gaussians are never flagged
    assert not _flags(cam, pos, parts, col, lpos, lcol, lseen, seen=~painted)[painted].any()
    # a sheer layer is not cloth to draw
    assert not _flags(cam, pos, parts, col, lpos, lcol, lseen, opacity=np.full(len(lpos), 0.3)).any()


def test_a_bare_hand_reads_its_own_colour_beside_a_sleeve_of_the_cloths():
    """A coat's sleeve in the cloth's colour (many Gaussians) and a bare hand: the hand's own colour
    is the hand's where it is off the cloth, not the whole arm's."""
    rng = np.random.default_rng(4)
    cam, pos, parts, col, lpos, lcol, lseen, painted = _scene(rng, sleeve=CLOTH, forearm=1500)
    out = _flags(cam, pos, parts, col, lpos, lcol, lseen)
    assert out[painted].mean() > 0.9 and not out[~painted].any()


def test_a_colour_near_the_cloth_but_nearer_the_limb_or_far_from_both_is_kept():
    """Skin a little off the cloth's colour (within ``tolerance`` of it, nearer the limb's) is the
    limb's; a dark watch over the cloth (nearer the cloth's colour than skin, beyond the tolerance)
    is not the cloth's."""
    rng = np.random.default_rng(5)
    near_skin = CLOTH + np.array([0.09, 0.04, -0.04])
    cam, pos, parts, col, lpos, lcol, lseen, painted = _scene(rng)
    col[parts == PART_INDEX["hand.L"]] = near_skin
    col[parts == PART_INDEX["lowerarm.L"]] = near_skin
    from reconstruct.avatar.layer_through import colour_distance

    d = colour_distance(near_skin[None], CLOTH[None])[0]
    assert 0.08 <= d <= 0.12, d
    assert not _flags(cam, pos, parts, col, lpos, lcol, lseen, max_share=1.0).any()
    cam, pos, parts, col, lpos, lcol, lseen, painted = _scene(rng)
    col[painted] = [0.05, 0.05, 0.06]
    assert not _flags(cam, pos, parts, col, lpos, lcol, lseen, max_share=1.0).any()


@pytest.mark.parametrize("reach", [0.02, 0.04])
def test_reach_sets_how_far_in_the_image_the_cloth_is_read(reach):
    """Against a direct count: the hand Gaussians over the cloth (at least ``k_cloth`` seen layer
    Gaussians within ``reach``, in metres at their depth) are the only ones that can be flagged."""
    rng = np.random.default_rng(3)
    cam, pos, parts, col, lpos, lcol, lseen, painted = _scene(rng)
    uv, z = cam.project(pos)
    luv, _ = cam.project(lpos)
    over = np.array([np.sum(np.linalg.norm(luv[lseen] - p, axis=1) <= reach * cam.fx / d) >= 4 for p, d in zip(uv, z)])
    col[:] = SKIN
    col[over] = np.clip(CLOTH + rng.uniform(-0.04, 0.04, (over.sum(), 3)), 0, 1)  # every one over the cloth drew it
    out = _flags(cam, pos, parts, col, lpos, lcol, lseen, reach=reach, max_share=1.0)
    assert over.any() and np.array_equal(out, over)
