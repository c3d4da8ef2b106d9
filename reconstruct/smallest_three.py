"""Unit quaternions stored as their "smallest three": the index of the largest component (by
magnitude, made positive) and the other three in order. SuperSplat's compressed ``.ply``, Niantic's
``.spz`` (v3-4) and PlayCanvas's SOG all store rotations this way; each quantises the three
differently."""

from __future__ import annotations

import numpy as np


def drop_largest(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the largest component's index (N,), the other three in order (N,3)) of quaternions (N,4),
    in whatever component order ``q`` is given; the sign is chosen so the largest is positive."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    n = len(q)
    largest = np.abs(q).argmax(1)
    q = q * np.where(q[np.arange(n), largest] < 0, -1.0, 1.0)[:, None]
    keep = np.ones_like(q, bool)
    keep[np.arange(n), largest] = False
    return largest, q[keep].reshape(n, 3)


def restore_largest(largest: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Quaternions (N,4) from ``drop_largest``'s output: the three back in their places, the
    largest from the unit norm (non-negative)."""
    largest = np.asarray(largest, np.int64)
    rest = np.asarray(rest, np.float64)
    n = len(largest)
    q = np.zeros((n, 4))
    keep = np.ones((n, 4), bool)
    keep[np.arange(n), largest] = False
    q[keep] = rest.reshape(-1)
    q[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - (rest ** 2).sum(1)))
    return q
