"""The body past the frame's edge (``appearance/cut_fill.py``, ``train/unseen_fill.out_of_view`` and
``cut_colors_of``): a photo cut at the hips shows nothing of the legs, and both legs take, alike, the
colour the image shows where they cross the edge; the flags come from projecting the posed
Gaussians into every training frame."""

import numpy as np
import pytest
import torch

from reconstruct.appearance.cut_fill import FrameView, apply_cut_colors, cut_colors
from reconstruct.appearance.wrap_fill import WrapFillConfig, wrap_fill_colors
from reconstruct.body.parts import PART_INDEX, PART_NAMES

H, W = 100, 80


def _tube(x: float, z0: float, z1: float, part: str, radius: float = 0.06, step: float = 0.01):
    """A vertical tube of Gaussians round (x, 0): positions, outward normals and its part."""
    zs = np.arange(z0, z1, step)
    th = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    z, t = np.meshgrid(zs, th, indexing="ij")
    n = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], -1).reshape(-1, 3)
    p = n * radius + np.stack([np.full_like(z, x), np.zeros_like(z), z], -1).reshape(-1, 3)
    return p, n, np.full(len(p), PART_INDEX[part])


def _person():
    """A torso over two legs (thigh and shin each), all tubes: positions, normals, parts."""
    pieces = [_tube(0.0, 0.9, 1.4, "torso", radius=0.15)]
    for side, x in (("L", 0.1), ("R", -0.1)):
        pieces += [_tube(x, 0.5, 0.9, f"thigh.{side}"), _tube(x, 0.05, 0.5, f"shin.{side}")]
    return (np.concatenate([p for p, _, _ in pieces]), np.concatenate([n for _, n, _ in pieces]),
            np.concatenate([k for _, _, k in pieces]))


def _frame(pos, cut_z: float, image_fill):
    """An orthographic front view (x right -> u, z up -> v) of 50 px per metre whose image ends
    at height ``cut_z``: the person below it projects past the bottom edge. ``image_fill(u, v)``
    paints the image; the mask is the person's projection."""
    s = 50.0
    u = W / 2 + s * pos[:, 0]
    v = H - 1 - s * (pos[:, 2] - cut_z)
    mask = np.zeros((H, W), np.float32)
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    mask[np.floor(v[inside]).astype(int), np.floor(u[inside]).astype(int)] = 1.0
    ys, xs = np.mgrid[0:H, 0:W]
    image = image_fill(xs, ys).astype(np.float32)
    return FrameView(np.c_[u, v], np.ones(len(pos), bool), image, mask)


def test_both_legs_past_the_edge_take_what_the_image_shows_where_they_cross_it():
    pos, _, parts = _person()
    navy, darker = np.array([0.1, 0.15, 0.35]), np.array([0.05, 0.08, 0.2])
    # the image: a skirt over the thighs, navy on the left leg's side (u > W/2), darker on the right's
    frame = _frame(pos, 0.7, lambda x, y: np.where((x >= W / 2)[..., None], navy, darker) * np.ones((H, W, 3)))
    beyond = ~frame.inside()
    legs = np.isin(parts, [PART_INDEX[p] for p in ("thigh.L", "shin.L", "thigh.R", "shin.R")])
    assert beyond[legs].any() and not beyond[parts == PART_INDEX["torso"]].any()
    assert frame.beyond_edges(legs) == ["bottom"]
    cut = cut_colors(parts, beyond, [frame], edge_px=2.0)
    np.testing.assert_array_equal(np.isfinite(cut).all(1), beyond & legs)  # the torso is in view
    # one colour for both legs: the per-channel median of the pixels under both legs' Gaussians
    # within 2 px of the bottom edge, both sides pooled (by hand)
    near = legs & ~beyond & (frame.uv[:, 1] >= H - 2.0)
    px = frame.image[np.floor(frame.uv[near, 1]).astype(int), np.floor(frame.uv[near, 0]).astype(int)]
    np.testing.assert_allclose(cut[beyond & legs], np.broadcast_to(np.median(px, 0), ((beyond & legs).sum(), 3)), atol=1e-6)
    assert np.abs(cut[beyond & legs][0] - 0.5 * (navy + darker)).max() < 0.03
    # the mask decides what counts: pixels off the person are not the clothes at the edge
    frame.mask[:, W // 2:] = 0.0
    one = cut_colors(parts, beyond, [frame], edge_px=2.0)
    np.testing.assert_allclose(one[beyond & legs][0], darker, atol=1e-6)


def test_legs_with_nothing_in_view_take_the_person_along_the_edge():
    pos, _, parts = _person()
    shirt = np.array([0.9, 0.9, 0.95])
    frame = _frame(pos, 1.1, lambda x, y: shirt * np.ones((H, W, 3)))  # a portrait cut at the waist
    beyond = ~frame.inside()
    torso = parts == PART_INDEX["torso"]
    cut = cut_colors(parts, beyond, [frame], edge_px=2.0)
    assert np.isfinite(cut[beyond]).all()
    np.testing.assert_allclose(cut[beyond & ~torso], np.broadcast_to(shirt, ((beyond & ~torso).sum(), 3)), atol=1e-6)
    # nothing out of view: all NaN; a garment layer's Gaussians (past the body's parts) are never set
    assert np.isnan(cut_colors(parts, np.zeros(len(parts), bool), [frame], edge_px=2.0)).all()
    layer = parts.copy()
    layer[beyond & ~torso] = 99
    assert np.isnan(cut_colors(layer, beyond, [frame], edge_px=2.0)[layer == 99]).all()
    with pytest.raises(ValueError, match="cut_colors: out_of_view has shape"):
        cut_colors(parts, beyond[:3], [frame], edge_px=2.0)


def test_apply_leaves_the_seen_and_what_a_layer_hides():
    parts = np.array([PART_INDEX["shin.L"]] * 4 + [99])
    colours = np.full((5, 3), 0.5)
    cut = np.full((5, 3), np.nan)
    cut[1:] = 0.1
    seen = np.array([False, True, False, False, False])
    ul = np.array([-1, -1, -1, 3, -1])
    out = apply_cut_colors(colours, parts, seen, cut, under_layer=ul)
    np.testing.assert_array_equal(out[:, 0], [0.5, 0.5, 0.1, 0.5, 0.5])
    with pytest.raises(ValueError, match="the cut colours have shape"):
        apply_cut_colors(colours, parts, seen, cut[:4])


def test_the_wrap_fill_paints_the_cut_only_when_given_it():
    pos, normals, parts = _person()
    beyond = pos[:, 2] < 0.7
    seen = ~beyond & (normals[:, 1] < -0.3)
    colours = np.full((len(pos), 3), 0.5)
    colours[parts == PART_INDEX["torso"]] = 0.9
    colours[seen & (parts == PART_INDEX["thigh.R"]) & (np.abs(normals[:, 0]) > 0.7)] = 0.02  # a dark silhouette edge
    cut = np.full((len(pos), 3), np.nan)
    cut[beyond] = (0.1, 0.15, 0.35)
    args = (torch.as_tensor(pos), parts, torch.as_tensor(seen), torch.as_tensor(colours))
    plain = wrap_fill_colors(*args).numpy()
    painted = wrap_fill_colors(*args, cut_colors=torch.as_tensor(cut)).numpy()
    off = wrap_fill_colors(*args, cut_colors=torch.as_tensor(cut), config=WrapFillConfig(cut_fill=False)).numpy()
    np.testing.assert_array_equal(off, plain)
    np.testing.assert_array_equal(painted[~beyond], plain[~beyond])
    np.testing.assert_allclose(painted[beyond], np.broadcast_to(cut[beyond][0], (beyond.sum(), 3)), atol=1e-6)
    # the part rules had painted the two legs differently
    left, right = beyond & (pos[:, 0] > 0.05), beyond & (pos[:, 0] < -0.05)
    assert np.abs(plain[left].mean(0) - plain[right].mean(0)).max() > 0.02
    with pytest.raises(ValueError, match=r"cut_colors must have shape \("):
        wrap_fill_colors(*args, cut_colors=torch.as_tensor(cut[:-1]))


def test_out_of_view_flags_and_cut_colours_follow_the_frames_image(tiny_scene, tiny_config, tmp_path):
    """A frame's camera that sees the whole person: nothing out of view, no cut colours. Its
    image moved up by half its height (the principal point moved down): the Gaussians projecting
    below the image (in float64, by hand) are out of view, in every frame, and get a colour."""
    from types import SimpleNamespace

    from reconstruct.camera import Camera
    from reconstruct.train.trainer import Trainer
    from reconstruct.train.unseen_fill import cut_colors_of, out_of_view

    t = Trainer(tiny_scene, tiny_config, tmp_path / "run")
    assert not out_of_view(t.state, t.data).any()
    assert torch.isnan(cut_colors_of(t.state, t.data)).all()
    frames = {}
    for i in t.data.frames:
        f = t.scene.frames[i]
        c = f.camera
        K = np.array(c.K, np.float64)
        K[1, 2] += c.height / 2
        shifted = Camera(K, c.R, c.t, c.width, c.height, name=c.name)
        # the image and mask as that camera would show them: the frame's top half, moved down
        image, mask = np.zeros_like(f.image), np.zeros_like(f.mask)
        image[c.height // 2:], mask[c.height // 2:] = f.image[:c.height - c.height // 2], f.mask[:c.height - c.height // 2]
        frames[i] = SimpleNamespace(camera=shifted, image=image, mask=mask)
    cut = SimpleNamespace(frames=list(t.data.frames), scene=SimpleNamespace(frames=frames))
    flags = out_of_view(t.state, cut).numpy()
    inside = np.zeros(len(flags), bool)
    for i, fr in frames.items():
        cam = fr.camera
        p = t.state.posed(i).means.detach().double().numpy()
        x = (np.asarray(cam.R) @ p.T).T + np.asarray(cam.t)
        u, v = cam.K[0, 0] * x[:, 0] / x[:, 2] + cam.K[0, 2], cam.K[1, 1] * x[:, 1] / x[:, 2] + cam.K[1, 2]
        inside |= (x[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    np.testing.assert_array_equal(flags, ~inside)
    assert 0.2 < flags.mean() < 0.8  # the legs, not all or nothing
    colours = cut_colors_of(t.state, cut).numpy()
    assert np.isfinite(colours[flags & (t.state.model.parts() < len(PART_NAMES))]).all() and np.isnan(colours[~flags]).all()
