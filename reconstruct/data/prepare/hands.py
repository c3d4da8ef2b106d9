"""The hand model's knuckles in place of the pose model's hand points, where they can be trusted.

The fit turns each hand at the wrist (``fit.FIT_BONES``) to put the knuckles of the index and little
fingers (the heads of Anny's ``finger2-1`` and ``finger5-1``) on the pose's ``*_index`` and ``*_pinky``
landmarks. The pose model's own hand points are too loose for that: on real photos they come out
7-8 px apart on a hand whose knuckles span about 15, and a hand holding a can was put along the can.
Mediapipe's hand model, run on a crop round each hand (``hand_crops.py``), finds the knuckles (its
landmarks 5 and 17). Before, the hands kept the forearm's direction, and a fitted hand that reached
past the photo's over a skirt took the skirt's colours (``docs/prepare.md``, "Hands").

A found hand is taken when it is a hand and it is this person's (``HandGate``): its knuckles span
at least ``min_spread`` of its palm's length (wrist to the middle knuckle; the hand model collapsed
the can-holding hand into a line, 0.03, where turned hands on the photos of shared/real keep
0.40-1.06), and its wrist lies within ``max_wrist_offset`` palm lengths of the pose's wrist (0.14-0.64
on the same photos and their mirror images, 0.82 once). Where a hand is not taken, or the hand model
did not run on the frame, the pose's index and pinky points are left out of the fit (visibility 0)
and the hand keeps the forearm's direction, as before. Detections from a detector without a hand model (``hands`` None) are left as
they are.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .detector import Detections
from .hand_crops import HAND_POINTS, SIDES
from .keypoints import LANDMARK_NAMES

# the hand model's landmarks used: wrist, the index, middle and little fingers' knuckles
WRIST, INDEX_KNUCKLE, MIDDLE_KNUCKLE, PINKY_KNUCKLE = 0, 5, 9, 17


@dataclass(frozen=True)
class HandGate:
    min_spread: float = 0.2  # the index-to-pinky knuckle span, in palm lengths, of a hand taken
    # palm lengths from the pose's wrist to the hand model's, at most: hands taken on the photos of
    # shared/real and their mirror images lie 0.14-0.64 off, and the grey-skirt photo mirrored put
    # one at 0.82 in ``prepare`` (refused at 0.8; the same hand unmirrored, 0.24); another person's
    # hand, or the hand model's worst on a synthetic clip, 2-5
    max_wrist_offset: float = 1.0
    min_palm_px: float = 2.0  # a palm shorter than this is no hand


def taken_hands(det: Detections, gate: HandGate = HandGate()) -> np.ndarray:
    """(T,2) bool: the hands found that pass the gate (the person's left hand first)."""
    T = det.num_frames
    if det.hands is None:
        return np.zeros((T, 2), bool)
    h = np.asarray(det.hands, np.float64)
    palm = np.linalg.norm(h[:, :, MIDDLE_KNUCKLE] - h[:, :, WRIST], axis=-1)
    spread = np.linalg.norm(h[:, :, INDEX_KNUCKLE] - h[:, :, PINKY_KNUCKLE], axis=-1)
    wrists = det.keypoints[:, [HAND_POINTS[s][0] for s in SIDES]]  # (T,2,2) the pose's
    offset = np.linalg.norm(h[:, :, WRIST] - wrists, axis=-1)
    safe = np.maximum(palm, 1e-9)
    return (np.asarray(det.hands_found, bool) & det.found[:, None] & (palm >= gate.min_palm_px)
            & (spread >= gate.min_spread * safe) & (offset <= gate.max_wrist_offset * safe))


def with_hand_keypoints(det: Detections, gate: HandGate = HandGate()) -> tuple[Detections, np.ndarray]:
    """(detections, taken (T,2) bool): the pose's ``*_index`` and ``*_pinky`` landmarks replaced by the
    hand model's knuckles where a hand is taken (visibility: the pose's wrist's), left out elsewhere
    (visibility 0). Unchanged when no hand model ran (``det.hands`` None)."""
    if det.hands is None:
        return det, np.zeros((det.num_frames, 2), bool)
    taken = taken_hands(det, gate)
    kp, vis = det.keypoints.copy(), det.visibility.copy()
    for k, side in enumerate(SIDES):
        wrist = HAND_POINTS[side][0]
        for name, lm in ((f"{side}_index", INDEX_KNUCKLE), (f"{side}_pinky", PINKY_KNUCKLE)):
            j = LANDMARK_NAMES.index(name)
            kp[taken[:, k], j] = det.hands[taken[:, k], k, lm]
            vis[:, j] = np.where(taken[:, k], vis[:, wrist], 0.0)
    return replace(det, keypoints=kp, visibility=vis), taken
