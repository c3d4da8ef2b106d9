import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads OpenMP (see reconstruct/__init__.py)
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@pytest.fixture(scope="session")
def anny_body():
    from reconstruct.body.anny_backend import AnnyBody

    return AnnyBody({"gender": 0.3, "age": 0.6, "weight": 0.55, "height": 0.6}, leg_spread_deg=5.0)


@pytest.fixture(scope="session")
def small_scene():
    """A tiny synthetic scene built without the disk cache."""
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    cfg = SyntheticConfig(seed=3, num_frames=4, image_size=96, num_eval_azimuths=8, eval_frames=1, texture_size=256)
    return build_synthetic_scene(cfg, progress=False)


@pytest.fixture(scope="session")
def tiny_scene():
    """A very small synthetic scene for training tests (64x64 images, 4 frames)."""
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    cfg = SyntheticConfig(seed=1, num_frames=4, image_size=64, num_eval_azimuths=8, eval_frames=1, texture_size=128)
    return build_synthetic_scene(cfg, progress=False)


@pytest.fixture
def tiny_config():
    from reconstruct.avatar.config import AvatarConfig
    from reconstruct.train.config import Stage1Config

    return Stage1Config(iters=30, eval_every_seconds=1e9, checkpoint_every_seconds=1e9, crop_margin=4,
                        avatar=AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8,
                                            pose_feature_channels=8, hidden=32))
