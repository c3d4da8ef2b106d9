"""benchmarks/layer_drift.py: Gaussians carried rigidly with their surface do not drift, a slide
along the surface reads as its standard deviation in-plane, a bob along the normal as normal drift."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.layer_drift import attach, drift, material_points, surface_samples

VERTS = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], np.float64)
FACES = np.array([[0, 1, 2], [0, 2, 3]])


def _frames(n=7, seed=0):
    rng = np.random.default_rng(seed)
    return [(Rotation.random(random_state=rng.integers(1 << 30)).as_matrix(), rng.normal(0, 0.3, 3)) for _ in range(n)]


def test_surface_samples_cover_every_triangle():
    fid, bary = surface_samples(FACES, 4)
    assert len(fid) == len(FACES) * 15 and set(fid) == {0, 1}
    np.testing.assert_allclose(bary.sum(1), 1.0)
    assert (bary >= -1e-12).all()
    with pytest.raises(ValueError, match="at least 1 subdivision"):
        surface_samples(FACES, 0)


def test_a_point_on_a_sample_is_attached_to_it():
    fid, bary = surface_samples(FACES, 6)
    pts = material_points(VERTS, FACES, fid[[5, 40]], bary[[5, 40]])
    f, b = attach(pts, VERTS, FACES, 6)
    np.testing.assert_allclose(material_points(VERTS, FACES, f, b), pts, atol=1e-12)


def test_rigid_motion_is_no_drift_and_a_slide_is_its_spread():
    rng = np.random.default_rng(3)
    points0 = np.column_stack([rng.uniform(0.01, 0.09, 20), rng.uniform(0.01, 0.09, 20), np.full(20, 0.004)])
    fid, bary = attach(points0, VERTS, FACES, 8)
    frames = _frames()
    verts = np.stack([VERTS @ R.T + t for R, t in frames])
    rigid = np.stack([points0 @ R.T + t for R, t in frames])
    t_dev, c_dev = drift(rigid, verts, FACES, fid, bary)
    np.testing.assert_allclose(t_dev, 0, atol=1e-12)
    np.testing.assert_allclose(c_dev, 0, atol=1e-12)
    # a slide along each Gaussian's triangle's first edge (x in the square's plane for both
    # triangles) by s_f, and a bob along the normal by h_f
    s = rng.normal(0, 0.003, len(frames))
    h = rng.normal(0, 0.001, len(frames))
    moved = np.stack([(points0 + [s[i], 0, 0]) @ R.T + t for i, (R, t) in enumerate(frames)])
    t_dev, c_dev = drift(moved, verts, FACES, fid, bary)
    on_x = fid == 0  # triangle 0's first edge runs along x; triangle 1's along the diagonal
    np.testing.assert_allclose(t_dev, s.std(), rtol=1e-9)  # a slide's length in-plane, whatever the edge
    np.testing.assert_allclose(c_dev, 0, atol=1e-12)
    assert on_x.any() and (~on_x).any()
    bobbed = np.stack([(points0 + [0, 0, h[i]]) @ R.T + t for i, (R, t) in enumerate(frames)])
    t_dev, c_dev = drift(bobbed, verts, FACES, fid, bary)
    np.testing.assert_allclose(t_dev, 0, atol=1e-12)
    np.testing.assert_allclose(c_dev, h.std(), rtol=1e-9)
