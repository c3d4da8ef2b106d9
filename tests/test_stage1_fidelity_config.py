"""Stage I settings: the paper's / earlier defaults on request, and run records written before the
Stage I fidelity settings existed load with the values they were trained with."""

from reconstruct.avatar.config import AvatarConfig
from reconstruct.train.config import Stage1Config


def test_paper_settings_are_the_earlier_defaults():
    p = Stage1Config.paper()
    assert p.lr_milestones == (1 / 3, 2 / 3) and p.cull_backfacing is None
    a = p.avatar
    assert (a.gaussian_resolution, a.decoded_resolution, a.splat, a.scale_floor, a.init_scale_factor,
            a.color_residual) == (128, 128, "sphere", 0.0, 0.6, False)
    d = Stage1Config()
    assert d.cull_backfacing is not None and d.avatar.splat == "disc" and d.avatar.decoded_resolution == 128
    assert AvatarConfig(gaussian_resolution=64).decoded_resolution == 64  # never finer than the Gaussians


def test_old_records_load_with_their_own_values():
    old = Stage1Config.paper().to_dict()
    for key in ("cull_backfacing", "lr_decay_start", "lr_final"):
        del old[key]
    for key in ("decode_resolution", "splat", "scale_floor", "color_residual", "color_residual_gain",
                "disc_thickness"):
        del old["avatar"][key]
    c = Stage1Config.from_dict(old)
    assert c.cull_backfacing is None and c.lr_schedule()(0.5) == 0.1
    assert c.avatar.splat == "sphere" and c.avatar.scale_floor == 0.0 and not c.avatar.color_residual
    # a record of the first disc runs (no gain yet) keeps the gain those runs trained with
    rec = Stage1Config().to_dict()
    del rec["avatar"]["color_residual_gain"]
    assert Stage1Config.from_dict(rec).avatar.color_residual_gain == 1.0
    assert Stage1Config.from_dict(Stage1Config().to_dict()) == Stage1Config()
