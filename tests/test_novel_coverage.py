"""Coverage in novel poses (`eval --novel walk`, reconstruct/train/novel_coverage.py): the ground
truth of a synthetic scene rendered in any pose reproduces the scene's own evaluation masks; an
avatar made of the ground-truth surfaces themselves scores (almost) no holes, while the body alone
leaves the skirt's silhouette open between the legs; the command reports it and refuses a scene
without ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from reconstruct.avatar.gaussian_sets import PosedGaussians
from reconstruct.data.synthetic.generator import (SyntheticConfig, build_synthetic_scene, loose_outfit_of,
                                                  render_truth_masks)
from reconstruct.train.novel_coverage import NOVEL_AZIMUTHS, novel_coverage, novel_views
from tiny_runs import train_tiny

SMALL = dict(seed=0, num_frames=3, image_size=128, num_eval_azimuths=4, eval_frames=1, texture_size=128)


@pytest.fixture(scope="module")
def skirt():
    scene = build_synthetic_scene(SyntheticConfig(clothing="skirt", **SMALL), progress=False)
    return scene, loose_outfit_of(scene)


@pytest.fixture(scope="module")
def tight():
    return build_synthetic_scene(SyntheticConfig(clothing="garment", **SMALL), progress=False)


def test_truth_masks_reproduce_the_scenes_evaluation_masks(skirt, tight):
    for scene, outfit in (skirt, (tight, None)):
        views = scene.eval_views
        masks, garment = render_truth_masks(scene, [scene.frames[v.frame_index].pose for v in views],
                                            [v.camera for v in views], outfit=outfit)
        assert (garment is None) == (outfit is None)
        for v, m in zip(views, masks):
            assert m.shape == v.mask.shape and m.sum() > 100
            # the scene stores its masks rounded to 8 bits
            assert np.abs(m - v.mask).max() <= 0.5 / 255 + 1e-6, v.camera.name
        if garment is not None:
            for m, g in zip(masks, garment):
                # the garment is part of the person; the skirt's silhouette is a good part of it
                assert (g > 0.5).sum() > 0.15 * (m > 0.5).sum()
                assert ((g > 0.5) & (m < 0.5)).sum() <= 0.002 * (g > 0.5).sum()


def test_truth_needs_a_synthetic_scene(tight):
    other = tight.__class__(**{**tight.__dict__, "meta": {"source": "video"}})
    with pytest.raises(ValueError, match="not a synthetic scene"):
        render_truth_masks(other, [], [])
    with pytest.raises(ValueError, match="needs a synthetic scene"):
        novel_views(other, tight.body_model())
    with pytest.raises(ValueError, match="at least 2 frames"):
        novel_views(tight, tight.body_model(), frames=1)


class SurfaceAvatar:
    """An 'avatar' of opaque round Gaussians (6 mm) on the ground-truth surfaces (vertices and face
    centres of the posed body, and of the garment when ``garment``)."""

    def __init__(self, outfit, garment: bool):
        self.outfit, self.garment = outfit, garment
        self.calls = 0

    def posed_at(self, pose):
        self.calls += 1
        v, _ = self.outfit.posed(pose)
        faces = self.outfit.faces
        keep = np.ones(len(faces), bool) if self.garment else ~self.outfit.garment_face_mask
        f = faces[keep]
        pts = np.concatenate([v[np.unique(f)], v[f].mean(axis=1)])
        n = len(pts)
        t = torch.as_tensor(pts, dtype=torch.float32)
        return PosedGaussians(t, torch.zeros(n, 3), torch.full((n, 3), 0.5), torch.full((n, 3), 0.006),
                              torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), torch.full((n,), 0.99))


def test_surface_avatar_has_no_holes_and_the_body_alone_leaves_the_skirt_open(skirt):
    scene, outfit = skirt
    views = novel_views(scene, outfit.body, "walk", frames=4)
    assert len(views) == 4 * len(NOVEL_AZIMUTHS)
    assert {v.azimuth_deg for v in views} == set(NOVEL_AZIMUTHS)
    # the walk moves the legs: the ground truth differs between poses
    front = [v for v in views if v.azimuth_deg == 0.0]
    assert np.abs(front[1].mask - front[3].mask).sum() > 50
    bg = torch.zeros(3)
    full = SurfaceAvatar(outfit, garment=True)
    rows, summary = novel_coverage(full, views, bg, scale=2)
    assert full.calls == 4  # posed once per pose, shared by the four cameras
    assert len(rows) == len(views)
    assert summary["novel_hole_fraction"] < 0.01, summary
    assert summary["novel_garment_hole_fraction"] < 0.01, summary
    # round Gaussians a third of a pixel wide, packed densely, still spill a pixel or two past the
    # silhouette (the limbs are a few pixels wide at 128 x 128)
    assert summary["novel_alpha_iou"] > 0.75, summary
    assert summary["novel_hole_fraction_max"] >= summary["novel_hole_fraction"]
    body_only = SurfaceAvatar(outfit, garment=False)
    _, s2 = novel_coverage(body_only, views, bg, scale=2)
    assert s2["novel_garment_hole_fraction"] > 0.08, s2
    assert s2["novel_alpha_iou"] < summary["novel_alpha_iou"]


def test_eval_command_reports_novel_coverage(tmp_path, capsys):
    from app.cli import main

    run = tmp_path / "run"
    train_tiny(run, 2)
    capsys.readouterr()
    assert main(["eval", str(run), "--json", "--novel", "walk", "--novel-frames", "3"]) == 0
    result = json.loads(capsys.readouterr().out)
    novel = result["novel"]
    assert novel["sequence"] == "walk" and len(novel["views"]) == 3 * len(NOVEL_AZIMUTHS)
    assert 0.0 <= novel["novel_hole_fraction"] <= 1.0 and novel["novel_garment_hole_fraction"] is None
    assert main(["eval", str(run), "--novel", "walk", "--novel-frames", "1"]) == 2
    assert "--novel-frames must be at least 2" in capsys.readouterr().err
