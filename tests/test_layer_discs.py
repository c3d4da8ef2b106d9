"""benchmarks/layer_discs.py: counts of long and thin opaque discs and the hem's steps."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location(
    "layer_discs", Path(__file__).resolve().parents[1] / "benchmarks" / "layer_discs.py")
layer_discs = importlib.util.module_from_spec(_spec)
sys.modules["layer_discs"] = layer_discs  # its dataclass looks its module up
_spec.loader.exec_module(layer_discs)


def _grid(R=10, C=8, step=0.01):
    z = -step * np.arange(R)
    theta = np.arange(C) * 2 * np.pi / C
    P = np.stack(np.broadcast_arrays(0.2 * np.cos(theta)[None], 0.2 * np.sin(theta)[None], z[:, None]), -1)
    return P.reshape(-1, 3)


def test_counts_only_opaque_discs_by_their_longer_in_plane_axis():
    R, C = 10, 8
    scales = np.full((R * C, 3), [0.01, 0.01, 0.001])
    scales[0] = [0.06, 0.01, 0.001]  # 6 cm, 6:1
    scales[1] = [0.01, 0.04, 0.001]  # 4 cm along the second axis, 4:1 (not more)
    scales[2] = [0.02, 0.004, 0.001]  # 5:1, short
    scales[3] = [0.08, 0.08, 0.001]  # long but transparent
    opacity = np.ones(R * C)
    opacity[3] = 0.1
    s = layer_discs.disc_stats(scales, opacity, _grid(R, C), (R, C))
    assert (s.layer, s.opaque) == (80, 79)
    assert (s.over_3cm, s.over_5cm, s.thin) == (2, 1, 2)
    assert s.hem_median_cm == pytest.approx(1.0)
    assert s.hem_step_cm == pytest.approx(1.0)


def test_a_ring_running_off_at_the_hem_shows_in_its_largest_step():
    R, C = 10, 8
    P = _grid(R, C).reshape(R, C, 3)
    P[-2, :, 0] += 0.07  # one hem row 7 cm sideways
    s = layer_discs.disc_stats(np.full((R * C, 3), 0.01), np.ones(R * C), P.reshape(-1, 3), (R, C))
    assert s.hem_step_cm == pytest.approx(100 * np.hypot(0.07, 0.01))
    with pytest.raises(ValueError, match="expected 80 Gaussians on a 10 x 8 grid"):
        layer_discs.disc_stats(np.zeros((79, 3)), np.ones(80), P.reshape(-1, 3), (R, C))
