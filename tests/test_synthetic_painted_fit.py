"""``fit=painted`` synthetic scenes: a loose garment's colours painted on the body under it, with no
garment mesh (the tight reference in the loose garment's own pattern)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from reconstruct.body.anny_backend import random_phenotype
from reconstruct.body.parts import PART_INDEX
from reconstruct.body.uv_map import build_uv_map
from reconstruct.data.load import parse_synthetic_spec, synthetic_cache_key
from reconstruct.data.scene import BodySpec
from reconstruct.data.synthetic.garment_mesh import build_garment, landmarks
from reconstruct.data.synthetic.garment_paint import garment_on_body
from reconstruct.data.synthetic.generator import (SyntheticConfig, build_synthetic_scene, loose_outfit_of,
                                                  synthetic_scene_name)

SMALL = dict(seed=0, num_frames=2, image_size=96, num_eval_azimuths=2, eval_frames=1, texture_size=256)


@pytest.fixture(scope="module")
def body():
    return BodySpec.anny(random_phenotype(np.random.default_rng(0)), 5.0).build()


def test_fit_is_validated():
    with pytest.raises(ValueError, match="fit must be one of"):
        SyntheticConfig(clothing="skirt", fit="baggy")
    with pytest.raises(ValueError, match="needs a loose garment"):
        SyntheticConfig(clothing="garment", fit="painted")
    c = parse_synthetic_spec("synthetic:seed=1,clothing=wide_trousers,fit=painted")
    assert c.fit == "painted" and not c.garment_mesh
    assert SyntheticConfig(clothing="coat").garment_mesh and not SyntheticConfig().garment_mesh


def test_cache_keys_of_the_default_fit_are_the_ones_made_before_it_existed():
    # keys computed by the code before the field was added: the scenes users have cached are found again
    assert synthetic_cache_key(SyntheticConfig()) == "7dfac9095160c10c"
    assert synthetic_cache_key(SyntheticConfig(clothing="independent")) == "12e7389dca22df6b"
    assert synthetic_cache_key(SyntheticConfig(seed=2, clothing="wide_trousers")) == "6cc212a2fdfb5df6"
    assert synthetic_cache_key(SyntheticConfig(clothing="skirt", num_frames=3)) == "42bd0ead09b5239f"
    painted = synthetic_cache_key(SyntheticConfig(seed=2, clothing="wide_trousers", fit="painted"))
    assert painted != "6cc212a2fdfb5df6"


def test_names_and_no_outfit_for_painted_scenes():
    assert synthetic_scene_name(SyntheticConfig(clothing="skirt", fit="painted")) == "synthetic-seed0-skirt-painted"
    assert synthetic_scene_name(SyntheticConfig(clothing="skirt")) == "synthetic-seed0-skirt"
    meta = lambda **kw: SimpleNamespace(meta={"source": "synthetic", "config": {**SMALL, **kw}})  # noqa: E731
    assert loose_outfit_of(meta(clothing="wide_trousers", fit="painted")) is None
    assert loose_outfit_of(meta(clothing="garment")) is None


def test_garment_on_body_takes_each_legs_tube_colour(body):
    """An atlas that paints the left trouser leg's half red and the right's blue: the thighs and
    shins take their own leg's colour, the feet (below the hem), the chest and the arms are not
    under the garment."""
    garment = build_garment(body, "wide_trousers")
    atlas = np.zeros((512, 512, 3), np.uint8)
    atlas[:, :256] = (255, 0, 0)  # tube 0 (the body's left, +X) takes the atlas's left half
    atlas[:, 256:] = (0, 0, 255)
    uv = build_uv_map(body, 128)
    inside, colour = garment_on_body(body, garment, atlas, uv)
    parts = uv.parts
    on = lambda *names: np.isin(parts, [PART_INDEX[n] for n in names])  # noqa: E731
    z = uv.positions.numpy()[:, 2]
    x = uv.positions.numpy()[:, 0]
    assert inside[on("thigh.L", "thigh.R")].mean() > 0.97
    assert inside[on("shin.L", "shin.R") & (z > garment.vertices[:, 2].min() + 0.05)].mean() > 0.97
    assert not inside[on("foot.L", "foot.R") & (z < garment.vertices[:, 2].min())].any()
    assert not inside[on("upperarm.L", "upperarm.R", "head")].any()
    # below the crotch, where the two tubes touch and either may be the nearer
    legs = inside & (z < landmarks(body)["hips"] - 0.25)
    left = legs & on("thigh.L", "shin.L") & (x > 0.03)
    right = legs & on("thigh.R", "shin.R") & (x < -0.03)
    assert left.sum() > 100 and right.sum() > 100
    # read bilinearly, as the renderer does: the tube's seam column blends with the next tube's
    assert (colour[left, 0] > colour[left, 2]).all() and (colour[right, 2] > colour[right, 0]).all()
    assert np.isclose(colour[left], (1, 0, 0), atol=1e-6).all(1).mean() > 0.97
    assert np.isclose(colour[right], (0, 0, 1), atol=1e-6).all(1).mean() > 0.97


def test_painted_scene_renders_the_pattern_without_the_mesh():
    """The painted trousers' silhouette is the body's (the tight scene's), not the loose one's,
    and inside it the legs wear the trousers' colours, not the tight scene's."""
    tight = build_synthetic_scene(SyntheticConfig(**SMALL), progress=False)
    loose = build_synthetic_scene(SyntheticConfig(clothing="wide_trousers", **SMALL), progress=False)
    painted = build_synthetic_scene(SyntheticConfig(clothing="wide_trousers", fit="painted", **SMALL), progress=False)
    f_t, f_l, f_p = tight.frames[0], loose.frames[0], painted.frames[0]
    assert "loose_garment" not in painted.meta and painted.meta["painted_garment"]["kind"] == "wide_trousers"
    assert painted.meta["painted_garment"]["pattern"] == loose.meta["loose_garment"]["pattern"]
    assert np.array_equal(f_p.mask > 0.5, f_t.mask > 0.5)
    assert (f_l.mask > 0.5).sum() > 1.05 * (f_p.mask > 0.5).sum()
    legs = (f_p.mask > 0.5) & (np.arange(96)[:, None] > 60)  # the lower third: the legs
    mean = lambda f: f.image[legs].mean(0)  # noqa: E731
    assert np.abs(mean(f_p) - mean(f_l)).max() < np.abs(mean(f_t) - mean(f_l)).max()
