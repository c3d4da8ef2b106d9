"""Hair worn down, read in the images (``appearance/long_hair.py``): the region the hair covers in a
frame, the span it covers behind, and which unseen Gaussians behind the head, neck and back take
its colour."""

import numpy as np
import pytest
from scipy import ndimage

from reconstruct.appearance.cut_fill import FrameView
from reconstruct.appearance.long_hair import (FACE_TOUCH, JOIN_REACH, down_the_middle, face_middle,
                                              falls_past_neck, hair_back_colors, hair_region, hair_rows,
                                              hung_from_above, middle_mean, share_near, smooth_cover)

H, W = 130, 80
CX = 40  # the face's middle column
HAIR = np.array([0.35, 0.20, 0.10])
LIT = np.array([0.80, 0.62, 0.40])  # lit strands among the hair
SKIN = np.array([0.85, 0.65, 0.55])
SHIRT = np.array([0.20, 0.30, 0.70])
TOL = 0.12


def _person(tip: int, *, shirt=SHIRT, buttons: bool = False, hat_gap: int = 0, right_tip: int | None = None):
    """A frontal picture: a head (hair round a face open at the chin), a neck, a torso in a shirt, and two strands of
    hair either side of the neck down to row ``tip``. Returns image, mask and the points (pixel
    coordinates) of the head's hair, the face's middle, the face's skin and the shirt's lower half.
    ``buttons``: a few hair-coloured pixels on the shirt; ``hat_gap``: the head's hair is a hat
    over rows < 14 and the hair below it starts ``hat_gap`` rows lower (an ear between);
    ``right_tip``: the right strand ends there instead."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:H, 0:W]
    image = np.zeros((H, W, 3))
    mask = np.zeros((H, W), np.float32)
    head = ((xx - CX) / 15.0) ** 2 + ((yy - 24) / 20.0) ** 2 <= 1
    face = ((xx - CX) / 9.0) ** 2 + ((yy - 31) / 15.0) ** 2 <= 1  # open at the chin
    neck = (np.abs(xx - CX) <= 6) & (yy >= 40) & (yy < 52)
    torso = (np.abs(xx - CX) <= 26) & (yy >= 50) & (yy < 125)
    right_tip = tip if right_tip is None else right_tip
    strands = (((np.abs(xx - (CX - 19)) <= 3) & (yy < tip)) | ((np.abs(xx - (CX + 19)) <= 3) & (yy < right_tip))) & (yy >= 24)
    for region, colour in ((torso, shirt), (neck, SKIN), (head, HAIR), (face, SKIN), (strands, HAIR)):
        image[region] = colour
        mask[region] = 1.0
    hair = (head & ~face) | strands
    # lit strands among shadowed ones: 3 x 3 patches, wider than a one-pixel closing joins
    spots = np.zeros((H, W), bool)
    spots[4:-4:6, 4:-4:6] = True
    lit = ndimage.binary_dilation(spots & hair, iterations=1, structure=np.ones((3, 3), bool)) & hair & (yy > 8)
    image[lit] = LIT
    if buttons:
        on = torso & (np.abs(xx - CX) <= 1) & (yy % 9 == 0) & (yy > 60)
        image[on] = HAIR
    if hat_gap:
        image[head & ~face & (yy < 14)] = HAIR - 0.06  # a hat near the hair's colour
        image[(head & ~face & (yy >= 14) & (yy < 14 + hat_gap)) | (strands & (yy < 14 + hat_gap))] = SKIN
    image = np.clip(image + rng.normal(0, 0.01, image.shape), 0, 1)
    pts = lambda m: np.c_[xx[m], yy[m]].astype(np.float64) + 0.5  # noqa: E731
    seeds = head & ~face & (yy < (14 if hat_gap else 20)) & ~lit
    middle = face & (np.abs(xx - CX) <= 6) & (yy >= 22) & (yy <= 34)
    lower = torso & (yy >= 90)
    return image, mask, pts(seeds), pts(middle), pts(face), pts(lower)


def _rows(tip: int, **kw):
    image, mask, seeds, middle, skin, shirt = _person(tip, **kw)
    return hair_rows(image, mask, seeds, middle, [skin, shirt], tolerance=TOL), image


def test_hair_worn_down_covers_the_span_its_strands_mark_down_to_their_tips():
    rows, image = _rows(tip=80)
    assert rows is not None and rows.end == 80
    # below the head the span reaches from strand to strand, symmetric about the face's middle
    for r in (45, 60, 75):
        assert rows.left[r] == pytest.approx(CX - 22, abs=1.0) and rows.right[r] == pytest.approx(CX + 23, abs=1.0)
    assert np.isnan(rows.left[85:]).all()
    # hair falling further on one side than the other still hangs from the whole back of the head
    lopsided, _ = _rows(tip=80, right_tip=55)
    assert lopsided.end == 80
    assert lopsided.left[75] == pytest.approx(CX - 22, abs=1.0) and lopsided.right[75] == pytest.approx(CX + 22, abs=1.0)
    # its colour mixes lit and shadowed strands without either extreme; the shirt between the
    # strands is not hair
    assert np.abs(rows.colour[60] - HAIR).max() < 0.08
    assert not rows.region[60, CX - 10: CX + 10].any()
    # the lit strands inside the hair are in it (holes filled); the face's middle is not
    lit = np.abs(image - LIT).max(2) < 0.05
    interior = ndimage.binary_erosion(lit | (np.abs(image - HAIR).max(2) < 0.05), iterations=4)
    assert (lit & interior).sum() > 20 and rows.region[lit & interior].all()
    assert not rows.region[24:33, CX - 5: CX + 5].any()


def test_hair_cut_short_ends_above_the_neck():
    short, _ = _rows(tip=36)
    long, _ = _rows(tip=80)
    neck = np.c_[np.full(12, CX), np.arange(40, 52)].astype(np.float64) + 0.5
    assert short.end <= 45 and not falls_past_neck(short, neck)
    assert falls_past_neck(long, neck)
    assert not falls_past_neck(long, np.zeros((0, 2)))


def test_a_top_in_the_hairs_colour_is_no_hair():
    """A rival group showing the hair's colours as often as the hair does wins them: the region is
    the head's, not the top's."""
    rows, _ = _rows(tip=80, shirt=HAIR)
    assert rows is None or not rows.region[60:].any()


def test_a_few_hair_coloured_buttons_are_no_rival():
    """A share test, not the nearest colour: a shirt with a few hair-coloured buttons among its
    rivals leaves the hair found down its strands (the nearest colour would hand them the hair)."""
    image, mask, seeds, middle, skin, shirt = _person(80, buttons=True)
    yy, xx = np.mgrid[0:H, 0:W]
    buttons = (np.abs(xx - CX) <= 1) & (yy % 9 == 0) & (yy >= 90)
    shirt = np.r_[shirt, np.c_[xx[buttons], yy[buttons]] + 0.5]  # the shirt's points include them
    rows = hair_rows(image, mask, seeds, middle, [skin, shirt], tolerance=TOL)
    assert rows is not None and rows.end == 80
    assert not rows.region[buttons].any()  # apart from the hair


def test_hair_below_a_hat_past_an_ear_joins_it():
    image, mask, seeds, middle, skin, shirt = _person(80, hat_gap=4)
    rows = hair_rows(image, mask, seeds, middle, [skin, shirt], tolerance=TOL)
    assert rows is not None and rows.end == 80
    gap = np.ptp(middle[:, 1])
    assert 4 < JOIN_REACH * gap  # the gap is within the reach
    # past the reach, the hair below the hat still frames the face (it touches the face's hull)
    image, mask, seeds, middle, skin, shirt = _person(80, hat_gap=int(JOIN_REACH * gap) + 4)
    far = hair_rows(image, mask, seeds, middle, [skin, shirt], tolerance=TOL)
    assert far is not None and far.end == 80


def _pieces(strand_col: int):
    """Hair-coloured pixels: a hat (rows 2-10, holding the seeds) and a strand (rows 40-80, 4
    columns from ``strand_col``), 30 rows apart; and a face's hull (rows 14-38, columns 30-49)."""
    like = np.zeros((90, 80), bool)
    like[2:11, 25:55] = True
    like[40:81, strand_col:strand_col + 4] = True
    face = np.zeros_like(like)
    face[14:39, 30:50] = True
    ys, xs = np.nonzero(like[:11])
    return like, ~face, (xs, ys), face


def test_a_strand_the_face_cuts_off_from_the_hair_is_hair_where_it_touches_the_face():
    """Strands over a shoulder that a turned face cuts off from the hair above: a piece within
    FACE_TOUCH pixels of the face's hull joins the hair however far it is from the seeds' pieces;
    one a few pixels off the hull, or with no hull given, joins only within the reach."""
    reach = 20 / JOIN_REACH  # a face height whose reach (20 px) falls short of the 30-row gap
    like, allowed, seeds, face = _pieces(50)  # the strand's first column is the hull's last + 1
    assert FACE_TOUCH >= 1
    region = hair_region(like, allowed, seeds, reach, face)
    assert region[40:81, 50:54].all() and region[2:11, 25:55].all()
    assert not hair_region(like, allowed, seeds, reach)[40:81].any()  # no hull: the reach alone
    like, allowed, seeds, face = _pieces(50 + FACE_TOUCH + 2)
    assert not hair_region(like, allowed, seeds, reach, face)[40:81].any()
    # within the reach it joins with or without the face
    assert hair_region(like, allowed, seeds, 40 / JOIN_REACH)[40:81].any()
    assert hair_region(like, allowed, seeds, 40 / JOIN_REACH, face)[40:81].any()


def test_too_few_seeds_on_the_person_read_nothing():
    image, mask, seeds, middle, skin, shirt = _person(80)
    assert hair_rows(image, mask, seeds[:10], middle, [skin, shirt], tolerance=TOL) is None
    off = seeds + np.array([200.0, 0.0])  # outside the image: clipped onto the background
    assert hair_rows(image, mask, off, middle, [skin, shirt], tolerance=TOL) is None


def _view(tip: int, points: np.ndarray):
    """The picture of ``_person`` with the Gaussians ``points`` (pixels) after the seeds, face and
    rival points (in that order)."""
    image, mask, seeds, middle, skin, shirt = _person(tip)
    neck = np.c_[np.full(12, CX), np.arange(40, 52)].astype(np.float64) + 0.5
    uv = np.concatenate([seeds, middle, skin, shirt, neck, points])
    idx = np.cumsum([0, len(seeds), len(middle), len(skin), len(shirt), len(neck), len(points)])
    groups = [np.arange(idx[i], idx[i + 1]) for i in range(6)]
    return FrameView(uv, np.ones(len(uv), bool), image, mask), groups


def test_unseen_gaussians_behind_take_the_hair_where_it_covers_them():
    # candidates: behind the head (row 20), behind the neck at the jaw's height (38) and below it
    # (46), on the upper back within the span (70) and outside it (70, beside the torso's edge), and
    # below the tips (100). Hair cut short covers the back of the head only: the neck behind the
    # jaw is within its span in the picture, but the hair does not fall past the neck
    points = np.array([[CX, 20], [CX, 38], [CX, 46], [CX, 70], [CX + 25, 70], [CX, 100]], np.float64) + 0.5
    hanging = np.array([False, True, True, True, True, True])
    for tip, covered in ((80, [True, True, True, True, False, False]), (36, [True, False, False, False, False, False])):
        view, (seeds, middle, skin, shirt, neck, cand) = _view(tip, points)
        out = hair_back_colors(len(view.uv), cand, seeds, middle, [skin, shirt], [view], tolerance=TOL,
                               hanging=hanging, neck=neck)
        got = np.isfinite(out[cand]).all(1)
        assert got.tolist() == covered, tip
        assert np.abs(out[cand[got]] - HAIR).max() < 0.1
        others = np.setdiff1d(np.arange(len(view.uv)), cand)
        assert np.isnan(out[others]).all()


def test_over_frames_a_gaussian_is_covered_where_at_least_half_of_its_frames_cover_it():
    points = np.array([[CX, 70]], np.float64) + 0.5
    long, (seeds, middle, skin, shirt, neck, cand) = _view(80, points)
    short, _ = _view(36, points)
    hanging = np.array([True])

    def covered(views):
        out = hair_back_colors(len(long.uv), cand, seeds, middle, [skin, shirt], views, tolerance=TOL,
                               hanging=hanging, neck=neck)
        return bool(np.isfinite(out[cand]).all())

    assert covered([long, short]) and not covered([long, short, short]) and covered([long])


def test_the_middle_mean_leaves_out_the_brightest_and_darkest_quarters():
    rng = np.random.default_rng(1)
    c = rng.random((41, 3))
    order = np.argsort(c.sum(1))
    ref = c[order[10:31]].astype(np.float64).mean(0)
    np.testing.assert_allclose(middle_mean(c), ref)
    np.testing.assert_allclose(middle_mean(c[:1]), c[0])


def test_share_near_counts_everything_within_the_radius_and_nothing_past_one_and_a_half():
    rng = np.random.default_rng(2)
    samples = rng.random((3000, 3))
    colours = rng.random((200, 3))
    r = 0.1
    share = share_near(samples, colours, r)
    d = np.abs(samples[None] - colours[:, None]).max(2)
    assert ((d <= r).mean(1) <= share + 1e-12).all()
    assert (share <= (d < 1.5 * r).mean(1) + 1e-12).all()
    assert (share_near(np.zeros((0, 3)), colours, r) == 0).all()


def _grid(n: int):
    """Texel neighbours (right, left, down, up; -1 past the edge) of an n x n grid."""
    i = np.arange(n * n).reshape(n, n)
    nb = np.full((n, n, 4), -1)
    nb[:, :-1, 0] = i[:, 1:]
    nb[:, 1:, 1] = i[:, :-1]
    nb[:-1, :, 2] = i[1:]
    nb[1:, :, 3] = i[:-1]
    return nb.reshape(-1, 4)


def test_smooth_cover_fills_a_hole_and_takes_a_strip_away():
    n = 24
    colours = np.full((n * n, 3), np.nan)
    block = np.zeros((n, n), bool)
    block[2:14, 2:14] = True
    strip = np.zeros((n, n), bool)
    strip[18:20, 2:22] = True  # two texels thick
    colours[block.ravel()] = [0.3, 0.2, 0.1]
    colours[strip.ravel()] = [0.3, 0.2, 0.1]
    hole = 7 * n + 7
    colours[hole] = np.nan
    out = smooth_cover(colours, np.arange(n * n), _grid(n))
    got = np.isfinite(out).all(1).reshape(n, n)
    # the block stays (its corners rounded by the opening), the strip goes, nothing else is covered
    assert got[5:11, 5:11].all() and got[block].mean() > 0.8
    assert not got[strip].any() and not got[~(block | strip)].any()
    np.testing.assert_allclose(out[hole], [0.3, 0.2, 0.1], atol=1e-6)
    # only the candidates change
    keep = np.setdiff1d(np.arange(n * n), np.flatnonzero(strip))
    out = smooth_cover(colours, keep, _grid(n))
    assert np.isfinite(out[strip.ravel()]).all()


def test_the_face_middle_is_the_front_of_the_head_round_the_nose():
    """On a head sphere with a nose: the middle holds the nose and the front round it, not the
    crown, the back or the sides."""
    rng = np.random.default_rng(3)
    v = rng.normal(size=(4000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    head = v * 0.1 + np.array([0.0, 0.0, 1.6])
    nose = np.array([[0.0, -0.12, 1.59]])
    pos = np.r_[head, nose]
    middle = face_middle(pos)
    height = np.ptp(pos[:, 2])
    assert middle[-1]
    assert (pos[middle, 1] < pos[:, 1].mean()).all()
    assert (np.abs(pos[middle, 0]) <= 0.19 * height + 1e-12).all()
    assert not middle[pos[:, 2] > 1.59 + 0.23 * height + 1e-9].any()
    front = (head[:, 1] < -0.09) & (np.abs(head[:, 2] - 1.59) < 0.02) & (np.abs(head[:, 0]) < 0.03)
    assert middle[:-1][front].all()
    assert face_middle(np.zeros((0, 3))).shape == (0,)


def test_a_gaussian_behind_is_read_where_its_twin_in_front_projects():
    """The back of a body turned from the camera projects beside its front: each candidate is read
    where its twin (the front's Gaussian at its place) projects."""
    points = np.array([[CX + 30, 70], [CX, 70]], np.float64) + 0.5  # a candidate beside the span, its twin in it
    view, (seeds, middle, skin, shirt, neck, idx) = _view(80, points)
    cand, twin = idx[:1], idx[1:]
    args = (len(view.uv), cand, seeds, middle, [skin, shirt])
    out = hair_back_colors(*args, [view], tolerance=TOL, hanging=np.array([True]), neck=neck, twins=twin)
    assert np.isfinite(out[cand]).all() and np.abs(out[cand] - HAIR).max() < 0.1
    alone = hair_back_colors(*args, [view], tolerance=TOL, hanging=np.array([True]), neck=neck)
    assert np.isnan(alone[cand]).all()


def test_a_part_is_covered_only_below_a_covered_part():
    colours = np.full((30, 3), 0.3)
    head, neck, back = np.arange(0, 10), np.arange(10, 20), np.arange(20, 30)
    np.testing.assert_allclose(hung_from_above(colours, [head, neck, back]), colours, rtol=1e-6)
    bare_neck = colours.copy()
    bare_neck[neck[:6]] = np.nan  # 40 % of the neck covered: the back below it is not
    out = hung_from_above(bare_neck, [head, neck, back])
    assert np.isnan(out[back]).all() and np.isfinite(out[head]).all() and np.isfinite(out[neck[6:]]).all()
    bare_head = colours.copy()
    bare_head[head] = np.nan
    assert np.isnan(hung_from_above(bare_head, [head, neck, back])[10:]).all()


def test_the_backs_cover_is_kept_where_it_hangs_down_the_middle():
    """Two pieces of cover on a back (a grid of points 5 mm apart): a sheet across the middle is
    kept, a patch on one shoulder, apart from it, goes."""
    xs, zs = np.meshgrid(np.arange(-0.2, 0.2001, 0.005), np.arange(1.2, 1.45, 0.005))
    pos = np.c_[xs.ravel(), np.full(xs.size, 0.1), zs.ravel()]
    colours = np.full((len(pos), 3), np.nan)
    sheet = (np.abs(pos[:, 0]) < 0.06) & (pos[:, 2] > 1.35)
    patch = (pos[:, 0] > 0.13) & (pos[:, 2] > 1.40)
    colours[sheet | patch] = 0.2
    out = down_the_middle(colours, np.arange(len(pos)), pos, middle_x=0.0)
    assert np.isfinite(out[sheet]).all() and np.isnan(out[patch]).all()
    off = down_the_middle(colours, np.arange(len(pos)), pos, middle_x=0.3)  # nothing reaches that column
    assert np.isnan(off).all()
