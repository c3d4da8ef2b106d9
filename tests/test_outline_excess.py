"""benchmarks/outline_excess.py: the excess and deficit of a rendered outline against the mask,
split by side and by whose Gaussians draw it, on hand-made coverage maps."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location(
    "outline_excess", Path(__file__).resolve().parents[1] / "benchmarks" / "outline_excess.py")
oe = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(oe)


def _legs(H=20, W=30):
    """A mask of two 'legs' (columns 8-11 and 18-21) over rows 5-14."""
    m = np.zeros((H, W), bool)
    m[5:15, 8:12] = True
    m[5:15, 18:22] = True
    return m


def test_row_sides_split_left_right_and_between():
    mask = _legs()
    cover = mask.copy()
    cover[5:15, 5:8] = True      # 3 px left of the left leg
    cover[5:10, 22:23] = True    # 1 px right of the right leg on 5 rows
    cover[7:9, 12:18] = True     # across the gap on 2 rows
    cover[0:2, 0:30] = True      # rows with no mask: neither side
    left, right, between = oe.row_sides(cover, mask)
    assert left.sum() == 30 and right.sum() == 5 and between.sum() == 12
    assert not (left & mask).any() and not (between & mask).any()


def test_view_excess_shares_and_owners():
    mask = _legs()
    area = mask.sum()
    cover = mask.copy()
    layer = np.zeros_like(mask)
    body = mask.copy()
    cover[5:15, 6:8] = True; layer[5:15, 6:8] = True          # 20 px drawn by the layer
    cover[5:15, 22:23] = True; body[5:15, 22:23] = True       # 10 px drawn by the body
    cover[5:10, 15] = True                                     # 5 px only together
    cover[5:15, 11] = False                                    # deficit: 10 px
    depth = np.full(mask.shape, 2.0)
    e = oe.view_excess(cover, mask, layer, body, depth, focal=100.0)
    assert e["excess"] == pytest.approx(35 / area)
    assert e["layer"] == pytest.approx(20 / area) and e["body"] == pytest.approx(10 / area)
    assert e["together"] == pytest.approx(5 / area)
    assert e["deficit"] == pytest.approx(10 / area)
    assert e["left"] == pytest.approx(20 / area) and e["right"] == pytest.approx(10 / area)
    # 2 px at 2 m with a 100 px focal length: 40 mm; 1 px: 20 mm
    assert e["left_mm"] == pytest.approx(40.0) and e["right_mm"] == pytest.approx(20.0)


def test_no_layer_and_perfect_cover_read_zero():
    mask = _legs()
    e = oe.view_excess(mask.copy(), mask, None, mask.copy(), np.ones(mask.shape), focal=50.0)
    assert e["excess"] == 0 and e["deficit"] == 0 and e["layer"] == 0
    assert e["left_mm"] == 0 and e["right_mm"] == 0


def test_per_azimuth_averages_frames():
    rows = [{"azimuth": 90.0, "seen": False, "frame": f, "excess": x, "deficit": 0.0} for f, x in ((0, 0.02), (1, 0.04))]
    rows.append({"azimuth": 0.0, "seen": True, "frame": 0, "excess": 0.01, "deficit": 0.0})
    out = oe.per_azimuth(rows)
    assert [a["azimuth"] for a in out] == [0.0, 90.0]
    assert out[1]["excess"] == pytest.approx(0.03) and out[1]["seen"] is False
