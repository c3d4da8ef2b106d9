"""Horizontal slices of a body: the polar radius of a slice's convex hull.

A garment that hangs round the body (a skirt, a coat) follows the convex envelope of the body's
cross-section at each height: the hull of both legs spans the gap between them. Rings of cloth
are drawn as ``centre + r(theta) * d(theta)`` with ``d(theta) = (sin theta, -cos theta)``
(0 = towards -Y, the front; +pi/2 = +X, the body's left). ``r`` must be the distance along the
ray to the hull's boundary. (The support function ``max_p (p - c) . d`` is NOT that: used as a
radius it bulges past the hull wherever the slice is much wider than deep, e.g. 4 cm in front of
and behind a pair of legs.)
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull


def ring_directions(thetas: np.ndarray) -> np.ndarray:
    """(T,2) unit directions (sin t, -cos t): 0 = the front (-Y), +pi/2 = the body's left (+X)."""
    thetas = np.asarray(thetas, np.float64)
    return np.stack([np.sin(thetas), -np.cos(thetas)], 1)


def hull_polar_radii(points: np.ndarray, centre: np.ndarray, thetas: np.ndarray) -> np.ndarray:
    """(T,) distance from ``centre`` to the boundary of the convex hull of 2-D ``points`` along
    ``ring_directions(thetas)``. ValueError when ``centre`` is not inside the hull."""
    points = np.asarray(points, np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 3:
        raise ValueError(f"hull_polar_radii: need (K>=3, 2) points, found shape {points.shape}")
    P = points[ConvexHull(points).vertices] - np.asarray(centre, np.float64)
    E = np.roll(P, -1, axis=0) - P
    d = ring_directions(thetas)
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    denom = cross(d[:, None, :], E[None])  # (T,K)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = cross(P[None], E[None]) / denom  # ray parameter where it meets edge k's line
        s = cross(P[None], d[:, None, :]) / denom  # edge parameter
    ok = (r > 0) & (s >= -1e-9) & (s <= 1 + 1e-9) & np.isfinite(r)
    r = np.where(ok, r, np.inf).min(1)
    if not np.isfinite(r).all():
        raise ValueError("hull_polar_radii: the centre is outside the points' convex hull")
    return r
