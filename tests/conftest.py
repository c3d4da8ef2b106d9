import os
import sys
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
