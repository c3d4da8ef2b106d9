"""Square crops round a person's hands, for mediapipe's hand model; numpy only (the worker's sibling).

The pose model's hand points (wrist, index and pinky) are its least sure ones: on real photos the
index and pinky points come out 7-8 px apart on a hand whose knuckles span about 15, and where a hand
holds a can they point along the can. Mediapipe's hand model (the legacy Hands solution, whose palm
detector and 21-landmark model ship in the same wheel) finds the knuckles where they are, but its
palm detector sees the whole image at 192 px, where a hand of a full-body photo is a few pixels. So
the worker cuts a square round each of the pose's hands, ``REACH`` times the hand's reach from the
wrist on each side, scales it to ``HAND_INPUT`` px and runs the hand model on that alone
(``mediapipe_worker.detect_hands``). This file computes the boxes and maps the landmarks back.
"""

from __future__ import annotations

import numpy as np

# pose landmark indices (wrist, index, pinky) of each hand, the person's own left and right
HAND_POINTS = {"left": (15, 19, 17), "right": (16, 20, 18)}
SIDES = ("left", "right")
HAND_INPUT = 256  # px: the side of the square the hand model sees
REACH = 3.0  # the box reaches this many times the hand's reach (wrist to the index/pinky middle) each way
MIN_REACH = 0.03  # of the image height: the least reach assumed (a hand the pose saw folded)
NUM_HAND_LANDMARKS = 21


def hand_box(points_px: np.ndarray, height: int) -> tuple[int, int, int]:
    """Square box (x0, y0, size) in pixels round one hand, from the pose's (3,2) wrist, index and pinky
    points in pixels; it may reach past the image (``crop_square`` pads)."""
    pts = np.asarray(points_px, np.float64)
    if pts.shape != (3, 2) or not np.all(np.isfinite(pts)):
        raise ValueError(f"hand_box: expected (3,2) finite wrist, index and pinky points, found {pts.shape}")
    tip = 0.5 * (pts[1] + pts[2])
    centre = 0.5 * (pts[0] + tip)
    reach = max(float(np.linalg.norm(tip - pts[0])), MIN_REACH * float(height))
    half = max(int(round(REACH * reach)), 4)
    return int(round(centre[0])) - half, int(round(centre[1])) - half, 2 * half


def crop_square(image: np.ndarray, box: tuple[int, int, int]) -> np.ndarray:
    """(size,size,C) the image's pixels in ``box`` (x0, y0, size), zeros where it reaches past the image."""
    x0, y0, size = box
    H, W = image.shape[:2]
    out = np.zeros((size, size) + image.shape[2:], image.dtype)
    xs0, ys0, xs1, ys1 = max(0, x0), max(0, y0), min(W, x0 + size), min(H, y0 + size)
    if xs1 > xs0 and ys1 > ys0:
        out[ys0 - y0:ys1 - y0, xs0 - x0:xs1 - x0] = image[ys0:ys1, xs0:xs1]
    return out


def uncrop(points_norm: np.ndarray, box: tuple[int, int, int]) -> np.ndarray:
    """(...,2) pixels in the image from (...,2) coordinates normalised to the crop ([0,1] across the box)."""
    x0, y0, size = box
    return np.asarray(points_norm, np.float64) * float(size) + np.array([x0, y0], np.float64)
