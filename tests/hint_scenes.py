"""What the tests of the garment layer's volume hint share (test_synthetic_loose_layer,
test_garment_layer_legs, test_garment_layer_torso): small synthetic scenes by clothing kind, and a
frame with its mask replaced (the evidence read from a doctored mask)."""

from __future__ import annotations

import dataclasses

import numpy as np

from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene


def clothing_scenes(kinds, **config) -> dict:
    """``{kind: scene}``: the synthetic scene of each clothing kind with the same ``config``."""
    return {k: build_synthetic_scene(SyntheticConfig(clothing=k, **config), progress=False) for k in kinds}


def with_mask(frame, mask):
    """``frame`` with ``mask`` (bool or float, (H,W)) as its mask."""
    return dataclasses.replace(frame, mask=np.asarray(mask).astype(np.float32))
