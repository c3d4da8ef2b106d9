"""The loose-clothing synthetic scenes (clothing=skirt|coat|dress|wide_trousers): garment geometry,
skinning over a walk, rendering, caching and the scene-folder round trip."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from reconstruct.body.anny_backend import random_phenotype
from reconstruct.data.scene import BodySpec
from reconstruct.data.synthetic.clothing import paint_clothing
from reconstruct.data.synthetic.garment_mesh import LOOSE_GARMENTS, build_garment
from reconstruct.data.synthetic.garment_skinning import max_edge_stretch, pose_garment
from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene
from reconstruct.data.synthetic.loose_outfit import dress
from reconstruct.data.synthetic.motion import walk_in_place

SMALL = dict(seed=0, num_frames=3, image_size=128, num_eval_azimuths=4, eval_frames=1, texture_size=256)


@pytest.fixture(scope="module")
def body_and_paint():
    rng = np.random.default_rng(0)
    body = BodySpec.anny(random_phenotype(rng), 5.0).build()
    painted = paint_clothing(body, rng, 256, "garment")
    poses = walk_in_place(body.bone_labels, 60, 20.0, rng)
    return body, painted, poses


@pytest.fixture(scope="module")
def outfits(body_and_paint):
    body, painted, _ = body_and_paint
    return {k: dress(body, k, painted, 0, 256) for k in LOOSE_GARMENTS}


@pytest.fixture(scope="module")
def scenes():
    return {k: build_synthetic_scene(SyntheticConfig(clothing=k, **SMALL), progress=False)
            for k in ("garment", "skirt", "coat")}


def test_garment_shell_is_closed_and_outward(outfits):
    for kind, o in outfits.items():
        g = o.garment
        # every edge of a closed shell is shared by exactly two faces
        f = g.faces
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _, counts = np.unique(e, axis=0, return_counts=True)
        assert (counts == 2).all(), f"{kind}: the shell is not closed ({(counts != 2).sum()} open edges)"
        # outer faces point away from the tube's axis (the ring centre at their height)
        v = g.vertices
        fo = f[g.outer[f].all(1)]
        n = np.cross(v[fo[:, 1]] - v[fo[:, 0]], v[fo[:, 2]] - v[fo[:, 0]])
        c = v[fo].mean(1)
        tube = g.tube[fo[:, 0]]
        axis = np.zeros_like(c)
        for t in np.unique(tube):
            on = g.outer & (g.tube == t)
            rows = g.grid_index[on, 0]
            centres = np.stack([np.bincount(rows, v[on, d]) / np.bincount(rows) for d in range(2)], 1)
            axis[tube == t, :2] = centres[g.grid_index[fo[tube == t, 0], 0]]
        radial = c[:, :2] - axis[:, :2]
        assert ((n[:, :2] * radial).sum(1) > 0).mean() > 0.99, kind


def test_garment_stands_off_the_body(body_and_paint, outfits):
    """The outer surface is outside the body: every outer vertex is at least the standoff away from
    the nearest body vertex of the parts it covers (the coat's shoulders where the arms come out
    aside)."""
    from scipy.spatial import cKDTree

    body = body_and_paint[0]
    tree = cKDTree(body.canonical_vertices.numpy())
    for kind, o in outfits.items():
        d, _ = tree.query(o.garment.vertices[o.garment.outer])
        assert np.percentile(d, 5) > 0.004, kind


def test_walk_does_not_tear_the_garment(body_and_paint, outfits):
    body, _, poses = body_and_paint
    for kind, o in outfits.items():
        g = o.garment
        worst = max(max_edge_stretch(g.vertices, pose_garment(body, g, o.weights, p), g.edges) for p in poses[::2])
        assert worst < 2.0, f"{kind}: an edge stretches {worst:.2f}x over the walk"


def test_nearest_vertex_weights_would_tear_the_skirt(body_and_paint, outfits):
    """The reason for blended weights: the skirt skinned by the nearest body vertex alone stretches
    far more between the legs than with the diffused weights."""
    from scipy.spatial import cKDTree

    body, _, poses = body_and_paint
    g = outfits["skirt"].garment
    sel = np.isin(body.vertex_parts, np.unique(body.vertex_parts))
    _, idx = cKDTree(body.canonical_vertices.numpy()[sel]).query(g.vertices)
    nearest = body.skin_weights.numpy()[sel][idx]
    torn = max(max_edge_stretch(g.vertices, pose_garment(body, g, nearest, p), g.edges) for p in poses[::2])
    blended = max(max_edge_stretch(g.vertices, pose_garment(body, g, outfits["skirt"].weights, p), g.edges)
                  for p in poses[::2])
    assert torn > 1.5 * blended


def _garment_masks(outfit, poses, camera):
    """Per pose, the garment's silhouette in ``camera`` for each of its tubes (trousers: one per
    leg; the gap between two trouser legs is not a hole in the garment)."""
    from renderer.gl_context import shared_offscreen_context
    from renderer.mesh_renderer import MeshRenderer

    g = outfit.garment
    renderers = []
    for t in np.unique(g.tube):
        f = g.faces[g.tube[g.faces[:, 0]] == t]
        renderers.append(MeshRenderer(shared_offscreen_context(), f, np.zeros((len(f), 3, 2)), None, supersample=1))
    try:
        out = []
        for p in poses:
            v, n = outfit.posed(p)
            nb = outfit.num_body_vertices
            out += [r.render(v[nb:], n[nb:], camera).mask > 0.5 for r in renderers]
        return out
    finally:
        for r in renderers:
            r.release()


@pytest.mark.parametrize("kind", LOOSE_GARMENTS)
def test_no_holes_open_in_the_garment_over_the_walk(body_and_paint, outfits, kind, scenes):
    """Front view, every second frame of the walk: the garment's own silhouette (per tube) has no holes."""
    _, _, poses = body_and_paint
    cam = scenes["garment"].frames[0].camera
    for i, m in enumerate(_garment_masks(outfits[kind], poses[::2], cam)):
        holes = ndimage.binary_fill_holes(m) & ~m
        assert m.sum() > 100
        assert holes.sum() <= 2, f"{kind}: {holes.sum()} hole pixels in the garment (image {i})"


def test_skirt_and_coat_cover_the_gap_between_the_knees(scenes):
    tight = scenes["garment"]
    body = tight.body_model()
    L = body.bone_labels
    for kind in ("skirt", "coat"):
        s = scenes[kind]
        assert s.name == f"synthetic-seed0-{kind}"
        for f_t, f_l in zip(tight.frames, s.frames):
            assert f_l.mask.sum() > 1.05 * f_t.mask.sum(), kind  # the silhouette grows
            J = body.posed_joints(f_t.pose).numpy()
            hip = 0.5 * (J[L.index("upperleg01.L")] + J[L.index("upperleg01.R")])
            knees = 0.5 * (J[L.index("lowerleg01.L")] + J[L.index("lowerleg01.R")])
            p = hip + 0.75 * (knees - hip)  # between the thighs, a quarter above the knees
            uv, _ = f_t.camera.project(p[None])
            u, v = int(uv[0, 0]), int(uv[0, 1])
            assert f_t.mask[v, u] < 0.5, "the tight scene should show the gap between the legs"
            assert f_l.mask[v, u] > 0.99, f"{kind}: the gap between the knees is not covered"


def test_normals_are_consistent(scenes):
    for kind in ("skirt", "coat"):
        for img in [f for f in scenes[kind].frames] + list(scenes[kind].eval_views):
            inside = ndimage.binary_erosion(img.mask > 0.99, iterations=2)
            n = img.normal[inside]
            assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=0.05), kind
            assert (n[:, 2] < 0.05).mean() > 0.97, f"{kind}: normals facing away from the camera"
            assert (img.normal[img.mask == 0] == 0).all()


def test_scene_folder_round_trip_and_cache_key(tmp_path, scenes):
    from reconstruct.data.load import parse_synthetic_spec, synthetic_cache_key
    from reconstruct.data.scene_io import read_scene, write_scene

    s = scenes["skirt"]
    write_scene(s, tmp_path / "skirt")
    r = read_scene(tmp_path / "skirt")
    assert r.name == s.name and len(r.frames) == len(s.frames) and len(r.eval_views) == len(s.eval_views)
    for a, b in zip(s.frames + s.eval_views, r.frames + r.eval_views):
        assert np.array_equal(getattr(a, "image"), getattr(b, "image"))
        assert np.array_equal(a.mask, b.mask)
        assert np.abs(a.normal - b.normal).max() < 1e-6
    assert r.meta["loose_garment"]["kind"] == "skirt"
    assert r.meta["config"]["clothing"] == "skirt"
    keys = {k: synthetic_cache_key(parse_synthetic_spec(f"synthetic:seed=0,clothing={k}"))
            for k in ("garment", "independent") + LOOSE_GARMENTS}
    assert len(set(keys.values())) == len(keys)
    with pytest.raises(ValueError, match="clothing must be one of"):
        parse_synthetic_spec("synthetic:seed=0,clothing=kilt")


def test_garment_hides_the_front_leak_regions(scenes):
    """The leak regions of the coat scene are rendered with the coat in front: the coat hides the
    shirt's back, so the emblem's region is (nearly) empty."""
    coat, tight = scenes["coat"], scenes["garment"]
    area = lambda s: sum(float(v.front_leak.regions[..., 0].sum()) for v in s.eval_views if not v.seen)
    assert area(coat) < 0.1 * max(area(tight), 1.0)


def test_unknown_garment_is_refused(body_and_paint):
    with pytest.raises(ValueError, match="unknown loose garment"):
        build_garment(body_and_paint[0], "kilt")
