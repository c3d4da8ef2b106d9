import hashlib
import json

import numpy as np
import pytest

from reconstruct.body.parts import PART_INDEX
from reconstruct.data.load import (
    DEFAULT_SCENE,
    canonical_scene_spec,
    load_scene,
    parse_synthetic_spec,
    recorded_scene_spec,
    synthetic_cache_key,
)
from reconstruct.data.scene_io import SceneFormatError, read_scene, write_scene
from reconstruct.data.synthetic.generator import (
    SyntheticConfig,
    build_synthetic_scene,
    check_body_in_view,
)
from reconstruct.data.synthetic.motion import walk_in_place


def test_scene_shape_and_seen_flags(small_scene):
    s = small_scene
    assert len(s.frames) == 4 and s.image_size == (96, 96)
    assert len({v.azimuth_deg for v in s.eval_views}) == 8
    for v in s.eval_views:
        a = abs((v.azimuth_deg + 180) % 360 - 180)
        assert v.seen == (a <= 45.0)
    assert any(v.seen for v in s.eval_views) and any(not v.seen for v in s.eval_views)
    for f in s.frames:
        assert f.mask.max() == 1.0 and 0.05 < f.mask.mean() < 0.6
        assert f.image.min() >= 0 and f.image.max() <= 1
        # black outside the body, normals unit length inside
        assert np.abs(f.image[f.mask == 0]).max() == 0
        inside = f.mask > 0.99
        assert np.abs(np.linalg.norm(f.normal[inside], axis=-1) - 1).max() < 0.02
        # the body faces the training camera: camera-space normals point back at it (z < 0)
        assert np.median(f.normal[inside][:, 2]) < -0.3


def test_back_view_differs_from_front_view(small_scene):
    front = next(v for v in small_scene.eval_views if v.azimuth_deg == 0)
    back = next(v for v in small_scene.eval_views if v.azimuth_deg == 180)
    m = (front.mask > 0.99) & (back.mask[:, ::-1] > 0.99)
    # mirror the back view so the silhouettes roughly overlap; garments share their base colour front
    # and back, but face/hair, the emblem and the back-only details differ
    diff = np.abs(front.image[m] - back.image[:, ::-1][m]).mean()
    assert diff > 0.03, diff


def test_texture_patterns_differ_front_and_back(anny_body):
    from reconstruct.body.uv_map import build_uv_map
    from reconstruct.data.synthetic.clothing import paint_texture

    tex = paint_texture(anny_body, np.random.default_rng(0), 256, clothing="independent")
    uv = build_uv_map(anny_body, 256)
    colors = tex[uv.texel_rc[:, 0], uv.texel_rc[:, 1]].astype(float)
    torso = (uv.parts == PART_INDEX["torso"]) & (uv.positions[:, 2].numpy() > 0.15)
    front = torso & (uv.normals[:, 1].numpy() < -0.5)
    back = torso & (uv.normals[:, 1].numpy() > 0.5)
    assert np.abs(colors[front].mean(0) - colors[back].mean(0)).sum() + abs(colors[front].std() - colors[back].std()) > 20


def test_synthetic_is_deterministic_and_seeded():
    cfg = SyntheticConfig(seed=7, num_frames=2, image_size=48, num_eval_azimuths=8, eval_frames=1, texture_size=128)
    a = build_synthetic_scene(cfg, progress=False)
    b = build_synthetic_scene(cfg, progress=False)
    c = build_synthetic_scene(SyntheticConfig(**{**cfg.__dict__, "seed": 8}), progress=False)
    assert np.array_equal(a.frames[1].image, b.frames[1].image)
    assert not np.array_equal(a.frames[1].image, c.frames[1].image)
    assert a.body != c.body


def test_motion_within_human_limits():
    import anny  # noqa: F401  (labels come from the model)

    from reconstruct.body.anny_backend import load_anny_model

    labels = list(load_anny_model().bone_labels)
    poses = walk_in_place(labels, 120, 20.0, np.random.default_rng(1))
    turn = np.degrees([p.global_orient[2] for p in poses])
    assert np.abs(turn).max() <= 35.0 + 1e-9 and np.ptp(turn) > 20
    knee = np.degrees([p.joint_rotations[labels.index("lowerleg01.L"), 0] for p in poses])
    hip = np.degrees([p.joint_rotations[labels.index("upperleg01.L"), 0] for p in poses])
    assert knee.min() >= 0 and knee.max() <= 140 and knee.max() > 20  # knees bend one way
    assert hip.max() <= 0 + 1e-9 and hip.min() >= -120
    for p in poses:
        assert np.degrees(np.abs(p.joint_rotations)).max() <= 60


def test_scene_folder_roundtrip(small_scene, tmp_path):
    folder = write_scene(small_scene, tmp_path / "scene")
    again = read_scene(folder)
    assert again.summary() == small_scene.summary()
    for a, b in zip(small_scene.frames, again.frames):
        assert np.array_equal(a.image, b.image) and np.array_equal(a.mask, b.mask)
        assert np.abs(a.normal - b.normal).max() < 1e-6
        assert np.allclose(a.pose.joint_rotations, b.pose.joint_rotations)
        assert np.allclose(a.camera.K, b.camera.K)
    assert again.body == small_scene.body
    assert [v.seen for v in again.eval_views] == [v.seen for v in small_scene.eval_views]
    assert np.array_equal(again.meta["texture"], small_scene.meta["texture"])
    assert again.name == small_scene.name == "synthetic-seed3-garment"
    # the front-leak information of the unseen views comes back as it was in memory
    assert sum(v.front_leak is not None for v in again.eval_views) == sum(not v.seen for v in again.eval_views) > 0
    for a, b in zip(small_scene.eval_views, again.eval_views):
        assert (a.front_leak is None) == (b.front_leak is None)
        if a.front_leak is not None:
            assert a.front_leak.names == b.front_leak.names
            assert np.array_equal(a.front_leak.regions, b.front_leak.regions)
            for ca, cb in zip(a.front_leak.colors, b.front_leak.colors):
                assert np.abs(ca - cb).max() < 1e-6
    # rewriting replaces the folder atomically and leaves no temporary folders behind
    write_scene(again, folder)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]


def test_bad_scene_folders_are_named(small_scene, tmp_path):
    with pytest.raises(SceneFormatError, match="no such scene folder"):
        read_scene(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SceneFormatError, match="not a WonderHuman scene folder"):
        read_scene(tmp_path / "empty")
    folder = write_scene(small_scene, tmp_path / "s")
    doc = json.loads((folder / "scene.json").read_text())

    (folder / "scene.json").write_text("{not json")
    with pytest.raises(SceneFormatError, match=r"scene.json: not valid JSON"):
        read_scene(folder)
    (folder / "scene.json").write_text(json.dumps({**doc, "frames": doc["frames"][:2]}))
    with pytest.raises(SceneFormatError, match=r"4 poses for 2 frames"):
        read_scene(folder)
    (folder / "scene.json").write_text(json.dumps({**doc, "frames": []}))
    with pytest.raises(SceneFormatError, match="no frames"):
        read_scene(folder)
    (folder / "scene.json").write_text(json.dumps(doc))
    (folder / "frames" / "rgb" / "000002.png").unlink()
    with pytest.raises(SceneFormatError, match=r"000002.png: missing \(frame 2 image\)"):
        read_scene(folder)
    import imageio.v3 as iio

    iio.imwrite(folder / "frames" / "rgb" / "000002.png", np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(SceneFormatError, match=r"image is 12x10, the camera expects 96x96"):
        read_scene(folder)


def test_camera_that_misses_the_body_is_an_error(anny_body):
    from reconstruct.camera import Camera

    joints = anny_body.canonical_joints.numpy()
    away = Camera.look_at([0, -3, 0], [0, -6, 0], width=64, height=64)
    with pytest.raises(ValueError, match="does not see the body"):
        check_body_in_view(away, joints, "frame 0")


def test_spec_parsing_and_errors():
    cfg = parse_synthetic_spec("synthetic:seed=4,frames=10,size=128")
    assert (cfg.seed, cfg.num_frames, cfg.image_size) == (4, 10, 128)
    with pytest.raises(ValueError, match="unknown key 'colour'"):
        parse_synthetic_spec("synthetic:seed=1,colour=3")
    with pytest.raises(ValueError, match="is not a int"):
        parse_synthetic_spec("synthetic:seed=x")
    with pytest.raises(ValueError, match="num_frames must be >= 1"):
        parse_synthetic_spec("synthetic:frames=0")
    with pytest.raises(SceneFormatError, match="no such scene folder"):
        load_scene("/nonexistent/scene")


def test_synthetic_cache_roundtrip(monkeypatch, tmp_path):
    monkeypatch.setenv("WONDERHUMAN_CACHE_DIR", str(tmp_path))
    spec = "synthetic:seed=2,frames=2,size=48,azimuths=8,eval_frames=1,texture_size=128"
    a = load_scene(spec, progress=False)
    assert len(list((tmp_path / "scenes").iterdir())) == 1
    b = load_scene(spec, progress=False)  # read back from the cache
    assert np.array_equal(a.frames[0].image, b.frames[0].image)


# ----- clothing models ---------------------------------------------------------------------------

# Checksums of a tiny scene made by the generator BEFORE the clothing models existed (every back an
# independent random colour): ``clothing=independent`` must reproduce it exactly.
ORIGINAL_SPEC = "synthetic:seed=1,frames=3,size=48,azimuths=8,eval_frames=1,texture_size=128"
ORIGINAL_PIXELS_SHA256 = "b326e5fc5f5537b213d9d98d4eb78d4613fcc849043b574d009c62576baef9bf"
ORIGINAL_TEXTURE_SHA256 = "f7f661c9e637377cb6299b41704618f9193a33ddfa783526a7e1feda12cfceb4"
# synthetic_cache_key of "synthetic:seed=2,frames=2,size=48,azimuths=8,eval_frames=1,texture_size=128"
# before the clothing models existed
ORIGINAL_CACHE_KEY = "0257ba69cb18667e"


def _pixels_sha256(scene) -> str:
    h = hashlib.sha256()
    for f in scene.frames:
        h.update(np.ascontiguousarray(f.image).tobytes())
        h.update(f.mask.tobytes())
    for v in scene.eval_views:
        h.update(np.ascontiguousarray(v.image).tobytes())
        h.update(v.mask.tobytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def both_clothings():
    return {c: build_synthetic_scene(parse_synthetic_spec(f"{ORIGINAL_SPEC},clothing={c}"), progress=False)
            for c in ("independent", "garment")}


def test_independent_clothing_reproduces_the_original_scene(both_clothings):
    old = both_clothings["independent"]
    tex = np.ascontiguousarray(old.meta["texture"])
    assert hashlib.sha256(tex.tobytes()).hexdigest() == ORIGINAL_TEXTURE_SHA256
    assert _pixels_sha256(old) == ORIGINAL_PIXELS_SHA256
    assert old.name == "synthetic-seed1"  # the name old checkpoints recorded


def test_garment_has_the_same_body_and_motion(both_clothings):
    old, new = both_clothings["independent"], both_clothings["garment"]
    assert new.body == old.body and new.name == "synthetic-seed1-garment"
    for a, b in zip(old.frames, new.frames):
        assert np.array_equal(a.pose.joint_rotations, b.pose.joint_rotations)
        assert np.array_equal(a.mask, b.mask)
    assert not np.array_equal(old.meta["texture"], new.meta["texture"])
    assert new.meta["clothing"]["model"] == "garment"


def _painted(seed: int, clothing: str, size: int = 256):
    from reconstruct.body.anny_backend import random_phenotype
    from reconstruct.body.uv_map import build_uv_map
    from reconstruct.data.scene import BodySpec
    from reconstruct.data.synthetic.clothing import paint_clothing

    rng = np.random.default_rng(seed)
    body = BodySpec.anny(random_phenotype(rng), 5.0).build()
    return body, build_uv_map(body, size), paint_clothing(body, rng, size, clothing)


@pytest.mark.parametrize("seed", range(6))
def test_garment_backs_continue_the_fronts(seed):
    from reconstruct.data.synthetic.clothing import mirror_partners

    _, uv, garment = _painted(seed, "garment")
    _, _, independent = _painted(seed, "independent")
    partner = mirror_partners(uv)
    ny = uv.normals[:, 1].numpy()
    clothed = np.isin(uv.parts, [PART_INDEX[p] for p in ("torso", "thigh.L", "thigh.R", "shin.L", "shin.R")])
    back = clothed & (partner >= 0) & (ny > 0.3)
    dist = lambda col: np.linalg.norm(col[back] - col[partner[back]], axis=1)
    # a back texel has the colour of the front texel it continues (up to the back-only details) ...
    assert np.median(dist(garment.texel_colors)) < 0.05
    assert np.median(dist(independent.texel_colors)) > 0.08  # ... which the original (random) backs did not
    # the front-only emblem is nowhere on the back
    emblem = garment.leak_colors["emblem"][0]
    torso_back = (uv.parts == PART_INDEX["torso"]) & (ny > 0.3)
    assert (np.linalg.norm(garment.texel_colors[torso_back] - emblem, axis=1) < 0.15).mean() < 0.002
    # the emblem is on the front
    torso_front = (uv.parts == PART_INDEX["torso"]) & (ny < -0.3)
    assert (np.linalg.norm(garment.texel_colors[torso_front] - emblem, axis=1) < 0.05).sum() > 20
    # the hair at the back of the head is the hair of the crown
    head = uv.parts == PART_INDEX["head"]
    z = uv.positions[:, 2].numpy()
    top = z[head].max()
    crown = np.median(garment.texel_colors[head & (z > top - 0.02)], axis=0)
    back_of_head = head & (ny > 0.5) & (z > top - 0.1)
    assert np.median(np.linalg.norm(garment.texel_colors[back_of_head] - crown, axis=1)) < 0.02
    # and the face (skin) only in front: its mirrored region on the back of the head is not skin
    skin = garment.leak_colors["face"][0]
    assert garment.leak_texels["face"].sum() > 50
    assert (np.linalg.norm(garment.texel_colors[garment.leak_texels["face"]] - skin, axis=1) > 0.2).all()


def test_clothing_spec_and_recorded_specs():
    assert parse_synthetic_spec("synthetic:seed=4").clothing == "garment"
    assert parse_synthetic_spec("synthetic:seed=4,clothing=independent").clothing == "independent"
    with pytest.raises(ValueError, match="clothing must be one of garment, independent"):
        parse_synthetic_spec("synthetic:clothing=random")
    # runs record the clothing model explicitly ...
    assert canonical_scene_spec(DEFAULT_SCENE) == "synthetic:seed=0,clothing=garment"
    assert canonical_scene_spec("synthetic:") == "synthetic:clothing=garment"
    assert canonical_scene_spec("synthetic:seed=1,clothing=independent") == "synthetic:seed=1,clothing=independent"
    assert canonical_scene_spec("/data/scene") == "/data/scene"
    # ... and a recorded spec without one was recorded before garments existed: independent backs
    assert parse_synthetic_spec(recorded_scene_spec("synthetic:seed=0")).clothing == "independent"
    assert recorded_scene_spec("synthetic:seed=0,clothing=garment") == "synthetic:seed=0,clothing=garment"
    assert recorded_scene_spec("zju:/data/377,frames=0:3") == "zju:/data/377,frames=0:3"
    assert recorded_scene_spec(canonical_scene_spec("synthetic:seed=5")) == "synthetic:seed=5,clothing=garment"


def test_cache_keys():
    spec = "synthetic:seed=2,frames=2,size=48,azimuths=8,eval_frames=1,texture_size=128"
    # the original clothes keep their cache folder; garments get their own
    assert synthetic_cache_key(parse_synthetic_spec(spec + ",clothing=independent")) == ORIGINAL_CACHE_KEY
    assert synthetic_cache_key(parse_synthetic_spec(spec)) != ORIGINAL_CACHE_KEY


def test_old_cache_folders_get_front_leak_information(monkeypatch, tmp_path):
    monkeypatch.setenv("WONDERHUMAN_CACHE_DIR", str(tmp_path))
    spec = "synthetic:seed=2,frames=2,size=48,azimuths=8,eval_frames=1,texture_size=128,clothing=independent"
    a = load_scene(spec, progress=False)
    (folder,) = (tmp_path / "scenes").iterdir()
    assert folder.name == f"synthetic-seed2-{ORIGINAL_CACHE_KEY}"
    # make it look like a folder written before scenes carried front-leak information
    doc = json.loads((folder / "scene.json").read_text())
    for e in doc["eval_views"]:
        (folder / e.pop("front_leak")["regions"]).unlink() if "front_leak" in e else None
    doc["meta"].pop("front_leak")
    (folder / "scene.json").write_text(json.dumps(doc))
    old = read_scene(folder)
    assert all(v.front_leak is None for v in old.eval_views)  # old folders stay readable
    b = load_scene(spec, progress=False)
    assert all((v.front_leak is None) == v.seen for v in b.eval_views)
    for va, vb in zip(a.eval_views, b.eval_views):
        assert np.array_equal(va.image, vb.image)
        if va.front_leak is not None:
            assert np.array_equal(va.front_leak.regions, vb.front_leak.regions)
    assert all((v.front_leak is None) == v.seen for v in read_scene(folder).eval_views)  # and written back


def test_long_hair_is_painted_down_the_back_and_over_the_shoulders_and_nothing_else_changes():
    """``hair=long`` paints the hair's colour on the back of the neck and the upper back to
    ``LONG_HAIR_FALL`` below the neck's joint, and as two strands over the shoulders in front; every
    other texel, and the draws (the same palette and choices), are the drawn hair's."""
    from reconstruct.body.anny_backend import random_phenotype
    from reconstruct.body.uv_map import build_uv_map
    from reconstruct.data.scene import BodySpec
    from reconstruct.data.synthetic.clothing import (LONG_HAIR_FALL, LONG_HAIR_HALF_WIDTH, STRAND_FALL, STRAND_IN,
                                                     STRAND_OUT, _Geometry, paint_clothing)

    rng = np.random.default_rng(3)
    body = BodySpec.anny(random_phenotype(rng), 5.0).build()
    state = rng.bit_generator.state
    drawn = paint_clothing(body, rng, 256, "garment")
    after_drawn = rng.bit_generator.state
    rng.bit_generator.state = state
    long = paint_clothing(body, rng, 256, "garment", hair="long")
    g = _Geometry(body, 256)
    uv = build_uv_map(body, 256)
    hair = drawn.texel_colors[(uv.parts == PART_INDEX["head"]) & (uv.normals[:, 1].numpy() > 0.5)]
    hair = np.median(hair, 0)
    changed = np.abs(long.texel_colors - drawn.texel_colors).max(1) > 1e-9
    assert changed.sum() > 200
    np.testing.assert_allclose(long.texel_colors[changed], np.tile(hair, (int(changed.sum()), 1)), atol=0.02)
    x = np.abs(g.p[:, 0] - g.head[0])
    below = g.neck_z - g.p[:, 2]
    trunk = np.isin(uv.parts, [PART_INDEX["torso"], PART_INDEX["neck"]])
    back = trunk & (g.front < 0.5) & (x <= LONG_HAIR_HALF_WIDTH) & (below <= LONG_HAIR_FALL)
    strands = trunk & (g.front >= 0.5) & (x >= STRAND_IN) & (x <= STRAND_OUT) & (below <= STRAND_FALL)
    neck_back = (uv.parts == PART_INDEX["neck"]) & (g.front < 0.5)
    covered = back | strands | neck_back
    assert not changed[~covered].any()
    assert np.abs(long.texel_colors[covered] - hair).max(1).max() < 0.02
    assert long.description["hair"]["long"] and "long" not in drawn.description["hair"]
    assert {k: v for k, v in long.description.items() if k != "hair"} == {k: v for k, v in drawn.description.items() if k != "hair"}
    assert rng.bit_generator.state == after_drawn  # the same draws: the scene's motion is the same


def test_long_hair_is_a_garment_models_choice_and_names_its_scene():
    from reconstruct.data.load import parse_synthetic_spec
    from reconstruct.data.synthetic.generator import SyntheticConfig, synthetic_scene_name

    cfg = parse_synthetic_spec("synthetic:seed=2,frames=1,hair=long")
    assert cfg.hair == "long" and synthetic_scene_name(cfg) == "synthetic-seed2-garment-longhair"
    assert synthetic_scene_name(SyntheticConfig(seed=2)) == "synthetic-seed2-garment"
    with pytest.raises(ValueError, match="hair must be one of"):
        SyntheticConfig(hair="curly")
    with pytest.raises(ValueError, match="hair must be one of"):
        SyntheticConfig(hair="long", clothing="independent")
