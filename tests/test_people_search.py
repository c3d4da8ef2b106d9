"""The people search of ``prepare`` between people who touch: distances to each person's 2D skeleton
(``skeleton_split``), and ``mediapipe_worker.search_people`` with stand-ins for mediapipe's Pose and
face detector that fail the way the real ones did on a group photo (one skeleton for two people who
lean together; a segmentation that takes in whoever touches its person)."""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from reconstruct.data.prepare.mediapipe_worker import search_people
from reconstruct.data.prepare.skeleton_split import (BONES, distance_to_segments, skeleton_segments,
                                                     split_by_skeleton)


def test_distance_to_segments_matches_points_sampled_along_the_bones():
    """Each pixel centre's distance to the nearest segment, against the nearest of 2001 points along
    every segment (float64); a zero-length segment is a point; no segments: infinitely far."""
    rng = np.random.default_rng(0)
    segs = rng.uniform(-5, 37, size=(5, 2, 2))
    segs[4, 1] = segs[4, 0]  # a point
    H, W = 24, 32
    got = distance_to_segments(segs, H, W)
    t = np.linspace(0.0, 1.0, 2001)[:, None]
    pts = np.concatenate([a + t * (b - a) for a, b in segs])  # (S*2001, 2)
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    pix = np.stack([xs.ravel(), ys.ravel()], 1)
    ref = np.sqrt(((pix[:, None, :] - pts[None]) ** 2).sum(-1)).min(1).reshape(H, W)
    step = max(np.hypot(*(b - a)) for a, b in segs) / 2000
    assert got.shape == (H, W) and got.dtype == np.float32
    assert np.all(got <= ref + 1e-4) and np.all(ref - got <= step)
    assert np.isinf(distance_to_segments(np.zeros((0, 2, 2)), 3, 4)).all()


def test_skeleton_segments_keep_the_seen_bones_and_flag_the_head():
    pts = np.arange(66, dtype=float).reshape(33, 2)
    vis = np.ones(33)
    segs, head = skeleton_segments(pts, vis)
    assert len(segs) == len(BONES) + 1  # and the neck
    np.testing.assert_allclose(segs[-1], [pts[[11, 12]].mean(0), pts[0]])
    assert head.tolist() == [a < 11 or b < 11 for a, b in BONES] + [True]
    vis[15] = 0.1  # the left wrist unseen: the forearm and the hand go
    segs2, head2 = skeleton_segments(pts, vis)
    assert len(segs2) == len(BONES) - 1 and not any(np.allclose(s, [pts[13], pts[15]]) for s in segs2)
    vis[:] = 0.0
    vis[11] = 1.0  # one landmark seen: every bone, so that the person still has a skeleton
    segs3, _ = skeleton_segments(pts, vis)
    assert len(segs3) == len(BONES) + 1


def test_split_by_skeleton_gives_every_pixel_to_the_nearest_person():
    """The first person's segmentation took in the second, who stands against them: where both hold a
    pixel it goes to the nearer skeleton; a pixel only one holds goes to the other only where the
    other's skeleton is more than twice as near (``STRANGER``); pixels outside every segmentation stay
    nobody's; one person keeps their segmentation."""
    H, W = 20, 40
    left, right = np.zeros((H, W), bool), np.zeros((H, W), bool)
    left[2:18, 2:30] = True  # took in most of the neighbour
    right[2:18, 18:38] = True  # and the neighbour a little of the first, past the middle
    d = np.stack([distance_to_segments(np.array([[[10.0, 2.0], [10.0, 18.0]]]), H, W),
                  distance_to_segments(np.array([[[30.0, 2.0], [30.0, 18.0]]]), H, W)])
    a, b = split_by_skeleton(np.stack([left, right]), d)
    assert not (a & b).any() and ((a | b) == (left | right)).all()
    assert (a[:, :20] == left[:, :20]).all() and not a[:, 20:].any()
    assert (b[:, 20:] == (left | right)[:, 20:]).all() and not b[:, :20].any()
    # columns 21-22 only the first holds: the second's bone (6.5-8.5 px) is not twice as near as the
    # first's (11.5-12.5): the first's; columns 26-27 only the first holds, the second's bone 2.5-3.5
    # px off against 16.5-17.5: the second's
    right[:, 21:23] = False
    right[:, 26:28] = False
    a, b = split_by_skeleton(np.stack([left, right]), d)
    assert a[2:18, 21:23].all() and not b[:, 21:23].any()
    assert b[2:18, 26:28].all() and not a[:, 26:28].any()
    assert (a | b)[left | right].all() and not (a | b)[~(left | right)].any()
    one = split_by_skeleton(left[None], d[:1])
    assert (one[0] == left).all()


# ----- search_people with stand-ins ----------------------------------------------------------------
BG = (200, 200, 200)


@dataclass
class _Person:
    face: tuple[int, int, int, int]  # (x0, y0, x1, y1) pixels
    body: tuple[int, int, int, int]
    face_colour: tuple[int, int, int]
    body_colour: tuple[int, int, int]


def _scene(people, H=200, W=240):
    img = np.full((H, W, 3), BG, np.uint8)
    for p in people:
        x0, y0, x1, y1 = p.body
        img[y0:y1, x0:x1] = p.body_colour
        x0, y0, x1, y1 = p.face
        img[y0:y1, x0:x1] = p.face_colour
    return img


def _visible_faces(img, people):
    """The people whose face shows (80 % of its pixels in its colour) in ``img`` (whole image coordinates)."""
    out = []
    for p in people:
        x0, y0, x1, y1 = p.face
        patch = img[y0:y1, x0:x1]
        if patch.size and (patch == p.face_colour).all(-1).mean() >= 0.8:
            out.append(p)
    return out


class _FaceAnchoredPose:
    """Like mediapipe's Pose: anchored at the largest face it sees. When another face is within two
    face widths of it: one skeleton for both (the body box spans both; ``crowded="merge"``) or
    nobody found (``"miss"``), the two ways the real one failed on a group photo. Its segmentation
    is every non-background body pixel in the body box. Finds nobody in a window (the scenes here
    need none)."""

    def __init__(self, people, full_shape, crowded: str = "merge", first_face_off: float = 0.0):
        self.people, (self.H, self.W), self.crowded = people, full_shape, crowded
        self.face_off = first_face_off  # the first detection's face landmarks this far down
        self.calls = self.windows = 0

    def process(self, img):
        self.calls += 1
        if img.shape[:2] != (self.H, self.W):  # a window: these scenes are all found in the whole image
            self.windows += 1
            return SimpleNamespace(pose_landmarks=None, segmentation_mask=None)
        faces = _visible_faces(img, self.people)
        if not faces:
            return SimpleNamespace(pose_landmarks=None, segmentation_mask=None)
        size = lambda p: (p.face[2] - p.face[0]) * (p.face[3] - p.face[1])  # noqa: E731
        anchor = max(faces, key=size)
        fw = anchor.face[2] - anchor.face[0]
        group = [p for p in faces if abs(np.mean(p.face[::2]) - np.mean(anchor.face[::2])) <= 2 * fw]
        if len(group) > 1 and self.crowded == "miss":
            return SimpleNamespace(pose_landmarks=None, segmentation_mask=None)
        bx0, by0 = min(p.body[0] for p in group), min(p.body[1] for p in group)
        bx1, by1 = max(p.body[2] for p in group), max(p.body[3] for p in group)
        lm = np.zeros((33, 4))
        lm[:, 3] = 0.9
        fx0, fy0, fx1, fy1 = anchor.face
        lm[0, :2] = [(fx0 + fx1) / 2, (fy0 + fy1) / 2]
        lm[1:7, :2] = lm[0, :2] + [0, -3]
        lm[[7, 9], :2] = [fx0, (fy0 + fy1) / 2]
        lm[[8, 10], :2] = [fx1, (fy0 + fy1) / 2]
        lm[:11, 1] += self.face_off
        self.face_off = 0.0
        xl, xr = bx0 + 0.25 * (bx1 - bx0), bx0 + 0.75 * (bx1 - bx0)
        for (a, b), y in (((11, 12), by0 + 10), ((13, 14), by0 + 40), ((15, 16), by0 + 65), ((17, 18), by0 + 70),
                          ((19, 20), by0 + 70), ((21, 22), by0 + 70), ((23, 24), by0 + 70), ((25, 26), by0 + 105),
                          ((27, 28), by1 - 8), ((29, 30), by1 - 4), ((31, 32), by1 - 2)):
            lm[a, :2], lm[b, :2] = [xl, y], [xr, y]
        body = np.zeros((self.H, self.W), bool)
        for p in self.people:
            x0, y0, x1, y1 = p.body
            body[y0:y1, x0:x1] = True
        box = np.zeros_like(body)
        box[by0:by1, bx0:bx1] = True
        seg = (body & box & (img != BG).any(-1)).astype(np.float32)
        lm[:, 0] /= self.W
        lm[:, 1] /= self.H
        lms = [SimpleNamespace(x=x, y=y, z=0.0, visibility=v) for x, y, _, v in lm]
        return SimpleNamespace(pose_landmarks=SimpleNamespace(landmark=lms), segmentation_mask=seg)


class _FaceFinder:
    def __init__(self, people):
        self.people = people

    def process(self, img):
        H, W = img.shape[:2]
        dets = [SimpleNamespace(location_data=SimpleNamespace(relative_bounding_box=SimpleNamespace(
            xmin=p.face[0] / W, ymin=p.face[1] / H, width=(p.face[2] - p.face[0]) / W,
            height=(p.face[3] - p.face[1]) / H))) for p in _visible_faces(img, self.people)]
        return SimpleNamespace(detections=dets or None)


def test_two_people_leaning_together_are_found_apart():
    """The pose stand-in finds one skeleton for two people whose faces are close. Blanking that
    skeleton's whole segmentation and its box's core (the search before) blanked the second person
    too: one person found. Blanked near its bones only, the second person's face and most of their
    body stay, and they are found next. Each ends up with the pixels of their own body (the merged
    skeleton's segmentation split by the skeletons, where both hold it)."""
    a = _Person((70, 20, 92, 42), (50, 48, 110, 190), (250, 220, 120), (180, 60, 60))
    b = _Person((104, 24, 124, 44), (110, 52, 165, 190), (250, 220, 121), (60, 60, 180))
    img = _scene([a, b])
    pose = _FaceAnchoredPose([a, b], img.shape[:2])
    marks, regions = search_people(img, pose, _FaceFinder([a, b]), max_people=4)
    assert len(marks) == 2, len(marks)
    noses = marks[:, 0, :2] * [img.shape[1], img.shape[0]]
    np.testing.assert_allclose(noses[0], [81, 31], atol=0.5)  # the larger face first, as mediapipe does
    np.testing.assert_allclose(noses[1], [114, 34], atol=0.5)
    assert not (regions[0] & regions[1]).any()
    # the second skeleton is b's own body; the first spans both and keeps what its bones reach of b
    # (blanked near them before b was found, so b's segmentation lacks it)
    body_b = np.zeros(img.shape[:2], bool)
    body_b[b.body[1]:b.body[3], b.body[0]:b.body[2]] = True
    body_a = np.zeros(img.shape[:2], bool)
    body_a[a.body[1]:a.body[3], a.body[0]:a.body[2]] = True
    assert regions[1][body_b].mean() > 0.2 and regions[1][body_a].mean() < 0.05
    assert regions[0][body_a].mean() > 0.9


def test_one_person_is_found_once_and_keeps_their_segmentation():
    a = _Person((70, 20, 92, 42), (50, 48, 110, 190), (250, 220, 120), (180, 60, 60))
    img = _scene([a])
    marks, regions = search_people(img, _FaceAnchoredPose([a], img.shape[:2]), _FaceFinder([a]), max_people=4)
    assert len(marks) == 1 and regions.shape == (1, *img.shape[:2])
    body = np.zeros(img.shape[:2], bool)
    body[a.body[1]:a.body[3], a.body[0]:a.body[2]] = True
    assert (regions[0] == body).all()


def test_people_apart_are_each_found_by_the_first_search():
    """Two people 40 px apart: found one after the other without the face pass (no face is left unheld)."""
    a = _Person((30, 20, 52, 42), (10, 48, 70, 190), (250, 220, 120), (180, 60, 60))
    x = 70 + 40
    b = _Person((x + 20, 24, x + 40, 44), (x, 52, x + 55, 190), (250, 220, 121), (60, 60, 180))
    img = _scene([a, b])
    pose = _FaceAnchoredPose([a, b], img.shape[:2])
    marks, regions = search_people(img, pose, _FaceFinder([a, b]), max_people=4)
    assert len(marks) == 2 and pose.calls - pose.windows == 3  # a, b, then nobody


def test_faces_nobody_was_found_at_are_looked_for_one_at_a_time():
    """The pose stand-in finds nobody where two faces are close (``"miss"``): the search finds the
    person standing apart and stops. The face finder still sees the two faces on the image with that
    person blanked; each is looked for with the other hidden, and found with their own body."""
    a = _Person((70, 20, 92, 42), (50, 48, 110, 190), (250, 220, 120), (180, 60, 60))
    b = _Person((104, 24, 124, 44), (110, 52, 165, 190), (250, 220, 121), (60, 60, 180))
    c = _Person((195, 14, 219, 38), (180, 44, 235, 190), (250, 220, 122), (60, 160, 60))
    img = _scene([a, b, c])
    pose = _FaceAnchoredPose([a, b, c], img.shape[:2], crowded="miss")
    marks, regions = search_people(img, pose, _FaceFinder([a, b, c]), max_people=4)
    noses = marks[:, 0, :2] * [img.shape[1], img.shape[0]]
    np.testing.assert_allclose(noses, [[207, 26], [81, 31], [114, 34]], atol=0.5)  # c; then a, the larger
    for p, r in zip((c, a, b), regions):
        body = np.zeros(img.shape[:2], bool)
        body[p.body[1]:p.body[3], p.body[0]:p.body[2]] = True
        assert r[body].mean() > 0.9 and r[~body].sum() == 0
    # a crowd the pose finds nobody in at all: the faces alone find them
    marks, _ = search_people(_scene([a, b]), _FaceAnchoredPose([a, b], img.shape[:2], crowded="miss"),
                             _FaceFinder([a, b]), max_people=4)
    assert len(marks) == 2


def test_a_face_the_first_pose_missed_is_not_a_second_person():
    """The first detection puts the face's landmarks on the chest: the face stays unblanked and nobody's
    nose is in it, and the pose finds the same person at it: the same torso, not a second person."""
    a = _Person((70, 20, 92, 42), (50, 48, 110, 190), (250, 220, 120), (180, 60, 60))
    img = _scene([a])
    pose = _FaceAnchoredPose([a], img.shape[:2], first_face_off=40.0)
    marks, _ = search_people(img, pose, _FaceFinder([a]), max_people=4)
    assert len(marks) == 1 and pose.calls - pose.windows >= 3  # found, nobody, again at the face
