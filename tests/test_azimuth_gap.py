"""benchmarks/azimuth_gap.py: per-azimuth means from `eval --json` reports and the side/back split."""

import importlib.util
import json
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location(
    "azimuth_gap", Path(__file__).resolve().parents[1] / "benchmarks" / "azimuth_gap.py")
azimuth_gap = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(azimuth_gap)


def _report(psnr_of, seen=(0, 30, 330), frames=(3, 30), iou=0.95):
    views = []
    for a in range(0, 360, 30):
        for j, f in enumerate(frames):
            views.append({"view": f"az{a}_{f}", "frame": f, "azimuth_deg": float(a) + 1e-9, "seen": a in seen,
                          "psnr": psnr_of(a) + (0.5 if j else -0.5), "ssim": 0.9, "lpips": None,
                          "hole_fraction": 0.0, "alpha_iou": iou})
    return {"views": views}


def test_per_azimuth_means_over_frames_and_marks_seen():
    table = azimuth_gap.per_azimuth(_report(lambda a: 30.0 + a / 100))
    assert sorted(table) == list(range(0, 360, 30))
    assert table[90]["psnr"] == pytest.approx(30.9)  # the two frames' -0.5 / +0.5 cancel
    assert table[90]["views"] == 2 and table[90]["alpha_iou"] == pytest.approx(0.95)
    assert table[0]["seen"] and table[330]["seen"] and not table[180]["seen"]


def test_groups_split_sides_from_back():
    assert [azimuth_gap.group_of(a) for a in (0, 30, 60, 90, 120, 150, 180, 210, 240, 270, 300, 330)] == [
        None, "sides", "sides", "sides", "sides", "back", "back", "back", "sides", "sides", "sides", "sides"]
    # a run that loses 3 dB at the sides only: its back equals the reference's
    ref = azimuth_gap.per_azimuth(_report(lambda a: 32.0))
    run = azimuth_gap.per_azimuth(_report(lambda a: 29.0 if azimuth_gap.group_of(a) == "sides" else 32.0))
    r, g = azimuth_gap.group_means(ref), azimuth_gap.group_means(run)
    assert g["back"] - r["back"] == pytest.approx(0.0)
    assert g["sides"] - r["sides"] == pytest.approx(-3.0)
    # 9 unseen azimuths, 6 of them sides (60, 90, 120, 240, 270, 300) and 3 back
    assert g["unseen"] - r["unseen"] == pytest.approx(-3.0 * 6 / 9)


def test_table_lists_differences_and_group_rows():
    ref = azimuth_gap.per_azimuth(_report(lambda a: 32.0))
    run = azimuth_gap.per_azimuth(_report(lambda a: 31.0 if a == 180 else 32.0, iou=0.9))
    text = azimuth_gap.format_table(["tight", "loose"], [ref, run])
    row180 = next(line for line in text.splitlines() if line.startswith("| 180 |"))
    assert row180.endswith("| -1.00 |") and "31.00 / 0.900" in row180
    assert next(line for line in text.splitlines() if "unseen back" in line).endswith("| -0.33 |")


def test_bad_reports_say_which_file(tmp_path, capsys):
    with pytest.raises(ValueError, match="x.json: expected the 'views' list"):
        azimuth_gap.per_azimuth({"seen_psnr": 30.0}, "x.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    good = tmp_path / "good.json"
    good.write_text(json.dumps(_report(lambda a: 30.0)))
    assert azimuth_gap.main([str(good), str(bad)]) == 2
    assert "bad.json" in capsys.readouterr().err
    assert azimuth_gap.main([str(good), str(good)]) == 0
    assert "mean, all unseen" in capsys.readouterr().out
