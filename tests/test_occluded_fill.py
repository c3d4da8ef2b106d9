"""A part the images cover but never show (``appearance/occluded_fill.py``, ``train/unseen_fill.
occluded_colors_of``): a photo's neck, hidden by the chin, takes what the image shows where its
Gaussians that face the camera project."""

import numpy as np
import pytest

from reconstruct.appearance.cut_fill import FrameView
from reconstruct.appearance.occluded_fill import occluded_colors
from reconstruct.body.parts import PART_INDEX

H, W = 60, 40
NECK = ("neck",)  # the parts read here; the torso beside them is not


def _neck_and_torso():
    """A neck (a tube of radius 5 cm, 1.50-1.60 m) above a torso tube: positions, normals, parts."""
    th, z = np.meshgrid(np.linspace(-np.pi, np.pi, 32, endpoint=False), np.linspace(1.5, 1.6, 11))
    n = np.c_[np.sin(th.ravel()), -np.cos(th.ravel()), np.zeros(th.size)]
    neck = n * 0.05 + np.c_[np.zeros(th.size), np.zeros(th.size), z.ravel()]
    th2, z2 = np.meshgrid(np.linspace(-np.pi, np.pi, 32, endpoint=False), np.linspace(1.1, 1.45, 11))
    n2 = np.c_[np.sin(th2.ravel()), -np.cos(th2.ravel()), np.zeros(th2.size)]
    torso = n2 * 0.15 + np.c_[np.zeros(th2.size), np.zeros(th2.size), z2.ravel()]
    parts = np.r_[np.full(len(neck), PART_INDEX["neck"]), np.full(len(torso), PART_INDEX["torso"])]
    return np.r_[neck, torso], np.r_[n, n2], parts


def _front_view(pos, normals, image, mask):
    """An orthographic view from the front (the camera at -y), 100 px per metre, centred on (0,
    1.35): the view, and each Gaussian's cosine between its normal and the direction to the camera."""
    u = W / 2 + 100 * pos[:, 0]
    v = H / 2 - 100 * (pos[:, 2] - 1.35)
    cos = -normals[:, 1]
    return FrameView(np.c_[u, v], np.ones(len(pos), bool), image, mask), cos


def test_a_parts_gaussians_facing_the_camera_take_the_image_where_they_project():
    pos, normals, parts = _neck_and_torso()
    skin = np.array([0.6, 0.4, 0.3])
    ys = np.arange(H)[:, None, None]
    image = np.where(ys < 20, skin, np.array([0.8, 0.1, 0.1])) * np.ones((H, W, 3))  # throat above, collar below
    mask = np.ones((H, W), np.float32)
    mask[:, :W // 2 - 3] = 0.0  # the person's pixels stop left of x = -3 cm
    view, cos = _front_view(pos, normals, image, mask)
    out = occluded_colors(parts, [(view, cos)], part_names=NECK)
    neck = parts == PART_INDEX["neck"]
    facing = neck & (cos >= 0.5)
    on_person = np.floor(view.uv[:, 0]) >= W // 2 - 3
    # every neck Gaussian projects where the image is skin (rows above 20) -- 3x3 windows inside it
    assert (np.floor(view.uv[neck, 1]) < 18).all()
    got = facing & on_person
    assert got.sum() > 20
    assert np.abs(out[got] - skin).max() < 1e-6
    # not those turned away (the back, the sides past 60 degrees), not off the person, not the torso
    assert np.isnan(out[~got]).all()
    assert (facing & ~on_person).any()


def test_the_median_over_frames_and_the_checks():
    pos, normals, parts = _neck_and_torso()
    mask = np.ones((H, W), np.float32)
    colours = [np.array(c) for c in ((0.2, 0.2, 0.2), (0.5, 0.4, 0.3), (0.9, 0.9, 0.9))]
    frames = [_front_view(pos, normals, c * np.ones((H, W, 3)), mask) for c in colours]
    out = occluded_colors(parts, frames, part_names=NECK)
    facing = (parts == PART_INDEX["neck"]) & (frames[0][1] >= 0.5)
    assert np.abs(out[facing] - colours[1]).max() < 1e-6
    # a frame where a Gaussian turned away gives it nothing: the median of the other two
    turned = frames[2][1].copy()
    turned[:] = -1.0
    out2 = occluded_colors(parts, frames[:2] + [(frames[2][0], turned)], part_names=NECK)
    assert np.abs(out2[facing] - (colours[0] + colours[1]) / 2).max() < 1e-6
    assert np.isnan(occluded_colors(parts, frames, part_names=("hand.L",))).all()
    with pytest.raises(ValueError, match="occluded_colors: cos has shape"):
        occluded_colors(parts, [(frames[0][0], frames[0][1][:-1])], part_names=NECK)


def test_occluded_colors_of_reads_the_front_of_the_neck_and_the_torso(tiny_scene, tiny_config, tmp_path):
    """``train.unseen_fill.occluded_colors_of`` on a trainer: every frame's image one colour inside
    the person's mask, so every Gaussian read takes it; the neck's and the torso's only, and those
    read face the frames' cameras -- the front of the body, the synthetic scene's cameras being in
    front of it -- (posed surface normals, against the direction to the camera computed here)."""
    from types import SimpleNamespace

    from reconstruct.train.trainer import Trainer
    from reconstruct.train.unseen_fill import occluded_colors_of

    t = Trainer(tiny_scene, tiny_config, tmp_path / "run")
    colour = np.array([0.2, 0.5, 0.7], np.float32)
    frames = {}
    for i in t.data.frames:
        f = t.scene.frames[i]
        frames[i] = SimpleNamespace(camera=f.camera, mask=f.mask, image=np.broadcast_to(colour, f.image.shape).copy())
    data = SimpleNamespace(frames=list(t.data.frames), scene=SimpleNamespace(frames=frames))
    out = occluded_colors_of(t.state, data).numpy()
    parts = t.state.model.parts()
    read = np.isfinite(out).all(1)
    wanted = np.isin(parts, [PART_INDEX["neck"], PART_INDEX["torso"]])
    assert read[wanted].mean() > 0.2 and not read[~wanted].any()
    assert np.abs(out[read] - colour).max() < 1e-6
    # the reading Gaussians face a camera within 60 degrees in some frame, by a hand computation
    faces = np.zeros(len(parts), bool)
    for i in data.frames:
        posed, normals = t.state.posed_with_surface_normals(i)
        m = posed.means.detach().double().numpy()
        to_cam = np.asarray(frames[i].camera.center, np.float64) - m
        cos = (to_cam * normals.detach().double().numpy()).sum(1) / np.linalg.norm(to_cam, axis=1)
        faces |= cos >= 0.5
    assert not (read & ~faces).any()
    front = t.state.model.base_normals.cpu().numpy()[:, 1] < 0  # the avatar faces -y
    assert front[read].mean() > 0.95
    assert np.isnan(occluded_colors_of(t.state, data, parts=()).numpy()).all()
