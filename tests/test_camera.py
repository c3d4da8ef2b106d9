import numpy as np
import pytest

from reconstruct.camera import Camera, angle_between_views, orbit_position


def test_look_at_projects_target_to_principal_point():
    cam = Camera.look_at([1.0, -3.0, 0.5], [0.2, 0.1, -0.1], width=320, height=200, fov_y_deg=40)
    uv, z = cam.project(np.array([[0.2, 0.1, -0.1]]))
    assert np.allclose(uv[0], [160.0, 100.0])
    assert z[0] > 0
    # +Z world (up) appears towards the top of the image (smaller v)
    uv_up, _ = cam.project(np.array([[0.2, 0.1, 0.4]]))
    assert uv_up[0, 1] < 100.0


def test_gl_matrices_reproduce_pixel_projection():
    rng = np.random.default_rng(0)
    K = np.array([[300.0, 0, 130.0], [0, 310.0, 90.0], [0, 0, 1]])
    cam = Camera.look_at([0.3, -2.5, 0.4], [0, 0, 0], K=K, width=256, height=192, near=0.1, far=20)
    pts = rng.uniform(-0.5, 0.5, (50, 3))
    uv, _ = cam.project(pts)
    clip = (cam.gl_projection() @ cam.gl_view() @ np.c_[pts, np.ones(50)].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    # NDC x in [-1,1] left to right; NDC y bottom to top while image rows go top to bottom
    u = (ndc[:, 0] + 1) * 0.5 * cam.width
    v = (1 - ndc[:, 1]) * 0.5 * cam.height
    assert np.allclose(np.c_[u, v], uv, atol=1e-9)
    assert np.all(np.abs(ndc[:, 2]) < 1)


def test_orbit_convention():
    assert np.allclose(orbit_position(0, 0, 2), [0, -2, 0])  # in front of an avatar facing -Y
    assert np.allclose(orbit_position(90, 0, 2), [2, 0, 0])
    assert np.allclose(orbit_position(0, 90, 2), [0, 0, 2], atol=1e-12)
    a = Camera.orbit(0, 0, 3)
    b = Camera.orbit(120, 0, 3)
    assert abs(angle_between_views(a, b, [0, 0, 0]) - 120) < 1e-9


def test_dict_roundtrip_and_scaling():
    cam = Camera.orbit(30, 10, 3, width=100, height=80, name="x", meta={"k": 1})
    again = Camera.from_dict(cam.to_dict())
    assert np.allclose(again.K, cam.K) and np.allclose(again.R, cam.R) and again.name == "x"
    big = cam.scaled(200, 160)
    uv, _ = cam.project(np.array([[0.1, 0.0, 0.2]]))
    uv2, _ = big.project(np.array([[0.1, 0.0, 0.2]]))
    assert np.allclose(uv2, 2 * uv)


def test_bad_cameras_are_named():
    with pytest.raises(ValueError, match=r"Camera.K: expected shape"):
        Camera(np.eye(2), np.eye(3), np.zeros(3), 10, 10)
    with pytest.raises(ValueError, match="not a rotation"):
        Camera(np.eye(3), 2 * np.eye(3), np.zeros(3), 10, 10)
    with pytest.raises(ValueError, match="non-finite"):
        Camera(np.eye(3), np.eye(3), np.array([0, np.nan, 0]), 10, 10)
    with pytest.raises(ValueError, match="image size must be positive"):
        Camera(np.eye(3), np.eye(3), np.zeros(3), 0, 10)
    with pytest.raises(ValueError, match="missing keys"):
        Camera.from_dict({"K": np.eye(3).tolist()})
