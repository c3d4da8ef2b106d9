"""Whose pixel is it, when people touch: distances to each person's 2D skeleton.

The people search (``mediapipe_worker.find_people``) finds one person at a time and blanks them out
before looking again. A segmenter's mask of one person takes in whoever stands against them (the
group photo's coats), so blanking that whole mask blanked the neighbour too, and the next detection
merged what was left of them with the person beside. Here each person's skeleton (their landmarks'
bones, torso and head) gives a distance map: a person is blanked only near their own bones, and at
the end each pixel of anyone's mask goes to the person whose skeleton is nearest, a person whose
mask does not hold it counting as further (``STRANGER``).

numpy only, no project imports: the mediapipe worker runs it in its own virtualenv (numpy<2).
"""

from __future__ import annotations

import numpy as np

# mediapipe landmark index pairs: torso (its outline and both diagonals, so that its inside is near a
# bone), arms to the index fingers, legs to the toes and heels, the head's nose-ear triangle
BONES = ((11, 12), (11, 23), (12, 24), (23, 24), (11, 24), (12, 23),
         (11, 13), (13, 15), (15, 19), (12, 14), (14, 16), (16, 20),
         (23, 25), (25, 27), (27, 29), (27, 31), (24, 26), (26, 28), (28, 30), (28, 32),
         (0, 7), (0, 8), (7, 8))
HEAD = frozenset(range(11))  # the face's landmarks: nose, eyes, ears, mouth
_SHOULDERS = (11, 12)
_NOSE = 0
MIN_VISIBILITY = 0.3


def skeleton_segments(points: np.ndarray, visibility: np.ndarray, *,
                      min_visibility: float = MIN_VISIBILITY) -> tuple[np.ndarray, np.ndarray]:
    """The person's bones in pixels from landmarks ``points`` (33, 2) and ``visibility`` (33,):
    (segments (S, 2, 2), head (S,) bool: the head's bones and the neck). The bones whose both ends are
    seen (at least ``min_visibility``) and the neck (the shoulders' middle to the nose) when those
    are; every bone when fewer than two are seen (a person found with unsure landmarks still gets a
    skeleton)."""
    points = np.asarray(points, np.float64)
    seen = np.asarray(visibility, np.float64) >= min_visibility
    bones = [(points[a], points[b], a in HEAD or b in HEAD) for a, b in BONES if seen[a] and seen[b]]
    if seen[list(_SHOULDERS)].all() and seen[_NOSE]:
        bones.append((points[list(_SHOULDERS)].mean(0), points[_NOSE], True))
    if len(bones) < 2:
        bones = [(points[a], points[b], a in HEAD or b in HEAD) for a, b in BONES]
        bones.append((points[list(_SHOULDERS)].mean(0), points[_NOSE], True))
    segs = np.asarray([(a, b) for a, b, _ in bones], np.float64).reshape(-1, 2, 2)
    return segs, np.asarray([h for _, _, h in bones], bool)


def distance_to_segments(segments: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H, W) float32: each pixel centre's distance in pixels to the nearest of ``segments`` (S, 2, 2)."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    if len(segments) == 0:
        return np.full((height, width), np.inf, np.float32)
    best = np.full((height, width), np.inf)
    for a, b in np.asarray(segments, np.float64):
        d = b - a
        n2 = float(d @ d)
        t = 0.0 if n2 == 0.0 else np.clip(((xs - a[0]) * d[0] + (ys - a[1]) * d[1]) / n2, 0.0, 1.0)
        best = np.minimum(best, np.hypot(xs - (a[0] + t * d[0]), ys - (a[1] + t * d[1])))
    return best.astype(np.float32)


# a person whose segmentation does not hold a pixel takes it only where their skeleton is this many
# times nearer than that of everyone who holds it: a segmentation takes in the neighbour who touches
# its person, and the neighbour's own segmentation can miss some of them
STRANGER = 2.0


def split_by_skeleton(regions: np.ndarray, distances: np.ndarray, *, stranger: float = STRANGER) -> np.ndarray:
    """(P, H, W) bool: each pixel of any of ``regions`` (P, H, W) goes to the person with the nearest
    skeleton (``distances`` (P, H, W), from ``distance_to_segments``; ties to the lower index), a person
    whose region does not hold it counting ``stranger`` times as far."""
    regions = np.asarray(regions, bool)
    if len(regions) < 2:
        return regions.copy()
    d = np.asarray(distances, np.float64) * np.where(regions, 1.0, float(stranger))
    owner = np.argmin(d, axis=0)
    anyone = regions.any(axis=0)
    return np.stack([anyone & (owner == p) for p in range(len(regions))])
