"""The front-leak ("tattoo") metric: 0 on the ground truth, high on a back painted with the mirrored
front, low on renders that are wrong without resembling the front-only details."""

import numpy as np
import pytest
import torch
from scipy import ndimage

from reconstruct.body.uv_map import build_uv_map
from reconstruct.data.load import parse_synthetic_spec
from reconstruct.data.synthetic.clothing import mirror_partners
from reconstruct.data.synthetic.generator import (
    build_synthetic_scene,
    render_scene_views,
)
from reconstruct.metrics.front_leak import FrontLeakInfo, front_leak, front_leak_mean

SPEC = "synthetic:seed=1,frames=3,size=96,azimuths=8,eval_frames=1,texture_size=256"


def mirrored_front_texture(scene) -> np.ndarray:
    """The scene's atlas with every backward-facing texel painted in the colour of its mirror
    partner on the front (the back of a body that copied its front)."""
    cfg = scene.meta["config"]
    body = scene.body_model()
    uv = build_uv_map(body, int(cfg["texture_size"]))
    tex = np.asarray(scene.meta["texture"])[..., :3]
    col = tex[uv.texel_rc[:, 0], uv.texel_rc[:, 1]].copy()
    partner = mirror_partners(uv)
    back = partner >= 0
    col[back] = col[partner[back]]
    atlas = np.zeros_like(tex)
    atlas[uv.texel_rc[:, 0], uv.texel_rc[:, 1]] = col
    _, (ri, ci) = ndimage.distance_transform_edt(~uv.mask, return_indices=True)
    return atlas[ri, ci]


@pytest.fixture(scope="module", params=["garment", "independent"])
def leak_scene(request):
    scene = build_synthetic_scene(parse_synthetic_spec(f"{SPEC},clothing={request.param}"), progress=False)
    views = [v for v in scene.eval_views if v.front_leak is not None]
    mirrored = render_scene_views(scene, mirrored_front_texture(scene), views)
    return scene, views, mirrored


def test_leak_info_on_unseen_views_only(leak_scene):
    scene, views, _ = leak_scene
    assert views and all(not v.seen for v in views)
    assert all(v.front_leak is None for v in scene.eval_views if v.seen)
    assert len(views) == sum(not v.seen for v in scene.eval_views)
    for v in views:
        info = v.front_leak
        assert info.names == ("emblem", "face") and info.regions.shape == v.mask.shape + (2,)
        assert 0 <= info.regions.min() and info.regions.max() <= 1
        assert (info.regions.max(-1) <= v.mask + 1e-6).all()  # on the body
    back = next(v for v in views if v.azimuth_deg == 180)
    assert back.front_leak.regions[..., 0].sum() > 10 and back.front_leak.regions[..., 1].sum() > 10


def test_ground_truth_scores_zero(leak_scene):
    _, views, _ = leak_scene
    for v in views:
        score = front_leak(v.image, v)
        assert score == 0.0 or (np.isnan(score) and v.front_leak.region_pixels() < 1)
    assert front_leak_mean([v.image for v in views], views) == 0.0


def test_mirrored_front_scores_high(leak_scene):
    _, views, mirrored = leak_scene
    scores = {v.azimuth_deg: front_leak(img, v) for v, img in zip(views, mirrored)}
    for az in (135.0, 180.0, 225.0):
        assert scores[az] > 0.5, scores
    assert front_leak_mean(mirrored, views) > 0.5, scores


def test_wrong_but_not_leaking_renders_score_low(leak_scene):
    _, views, _ = leak_scene
    black = [np.zeros_like(v.image) for v in views]
    flat = [v.mask[..., None] * (v.image * v.mask[..., None]).sum((0, 1)) / v.mask.sum() for v in views]
    assert front_leak_mean(black, views) < 0.05
    assert front_leak_mean(flat, views) < 0.1


def test_definition_on_a_handmade_view():
    H = W = 10
    regions = np.zeros((H, W, 1), np.float32)
    regions[2:8, 2:8] = 1.0  # 36 pixels
    red, blue = np.array([0.9, 0.1, 0.1]), np.array([0.1, 0.2, 0.8])
    info = FrontLeakInfo(("emblem",), regions, (red[None],))
    truth = np.tile(blue, (H, W, 1))
    assert front_leak(truth, info, truth) == 0.0
    assert front_leak(np.tile(red, (H, W, 1)), info, truth) == 1.0
    assert front_leak(np.tile(0.88 * red, (H, W, 1)), info, truth) == 1.0  # shaded albedo still counts
    half = truth.copy()
    half[2:5, 2:8] = red
    assert front_leak(half, info, truth) == pytest.approx(0.5)
    # a colour merely nearer the detail than the truth is no leak (tolerance)
    assert front_leak(np.tile([0.6, 0.3, 0.3], (H, W, 1)), info, truth) == 0.0
    # torch images are accepted
    assert front_leak(torch.as_tensor(half), info, torch.as_tensor(truth)) == pytest.approx(0.5)
    # no visible region: NaN
    empty = FrontLeakInfo(("emblem",), np.zeros((H, W, 1)), (red[None],))
    assert np.isnan(front_leak(truth, empty, truth))


def test_errors_name_what_is_missing(small_scene):
    seen = next(v for v in small_scene.eval_views if v.seen)
    with pytest.raises(ValueError, match="no front-leak information"):
        front_leak(seen.image, seen)
    info = FrontLeakInfo(("emblem",), np.zeros((4, 4, 1)), (np.ones(3),))
    with pytest.raises(ValueError, match="ground-truth image"):
        front_leak(np.zeros((4, 4, 3)), info)
    with pytest.raises(ValueError, match="must be"):
        front_leak(np.zeros((5, 4, 3)), info, np.zeros((5, 4, 3)))
    with pytest.raises(ValueError, match="2 names"):
        FrontLeakInfo(("a", "b"), np.zeros((4, 4, 1)), (np.ones(3),))
