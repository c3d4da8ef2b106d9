"""body/slices.py: the polar radius of a slice's convex hull, checked against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruct.body.slices import hull_polar_radii, ring_directions


def test_directions_front_is_minus_y_and_left_is_plus_x():
    d = ring_directions(np.array([0.0, np.pi / 2, np.pi]))
    np.testing.assert_allclose(d, [[0, -1], [1, 0], [0, 1]], atol=1e-12)


def test_square_radii_match_the_closed_form():
    a = 0.3
    pts = np.array([[-a, -a], [a, -a], [a, a], [-a, a], [0.1, 0.05], [-0.2, 0.1]])  # inner points ignored
    th = np.linspace(0, 2 * np.pi, 73)
    want = a / np.maximum(np.abs(np.sin(th)), np.abs(np.cos(th)))
    np.testing.assert_allclose(hull_polar_radii(pts, np.zeros(2), th), want, rtol=1e-9)


def test_wide_slice_ring_stays_inside_the_hull_where_the_support_function_bulges():
    """Two 'legs' side by side (wide, shallow): the ring's points lie on the hull (depth within the
    slice's), while the support function used as a radius would stand 2+ cm in front of it."""
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    leg = np.stack([0.07 * np.cos(t), 0.07 * np.sin(t)], 1)
    pts = np.concatenate([leg + [-0.1, 0.0], leg + [0.1, 0.0]])
    th = np.linspace(0, 2 * np.pi, 128, endpoint=False)
    r = hull_polar_radii(pts, pts.mean(0), th)
    ring = r[:, None] * ring_directions(th)
    assert np.abs(ring[:, 1]).max() <= 0.07 + 1e-6
    assert np.abs(ring[:, 0]).max() == pytest.approx(0.17, abs=1e-4)
    support = np.array([(pts @ d).max() for d in ring_directions(th)])
    bulge = support[:, None] * ring_directions(th)
    assert np.abs(bulge[:, 1]).max() > 0.07 + 0.02


def test_ellipse_radii_match_the_closed_form():
    a, b = 0.25, 0.12
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    pts = np.stack([a * np.cos(t), b * np.sin(t)], 1)
    th = np.linspace(0, 2 * np.pi, 37)
    want = 1 / np.sqrt(np.sin(th) ** 2 / a ** 2 + np.cos(th) ** 2 / b ** 2)
    np.testing.assert_allclose(hull_polar_radii(pts, np.zeros(2), th), want, rtol=1e-4)


def test_bad_input_is_a_clear_error():
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    with pytest.raises(ValueError, match="outside"):
        hull_polar_radii(sq, np.array([2.0, 2.0]), np.array([0.0, 1.0]))
    with pytest.raises(ValueError, match=r"\(K>=3, 2\)"):
        hull_polar_radii(sq[:2], np.zeros(2), np.array([0.0]))
