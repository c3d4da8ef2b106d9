"""The loose-clothing target table (benchmarks/loose_targets.py): what it reads from `eval --json`
outputs, where each target's boundary lies, which tight run a garment is held against, and the
errors for outputs it cannot score."""

import json

import pytest

from benchmarks.loose_targets import Scores, collect, parse_before, table, tight_table, tight_verdict, verdict


def _eval(seen=(34.0, 0.981, 0.002), unseen=(30.0, 0.965, 0.004), walk=0.003, scale=2, step=2770):
    result = {"run": "r", "scene": "s", "step": step, "scale": scale,
              "seen_psnr": seen[0], "seen_alpha_iou": seen[1], "seen_hole_fraction": seen[2],
              "unseen_psnr": unseen[0], "unseen_alpha_iou": unseen[1], "unseen_hole_fraction": unseen[2],
              "views": []}
    if walk is not None:
        result["novel"] = {"sequence": "walk", "novel_hole_fraction": walk, "views": []}
    return result


def _write(runs, name, result):
    (runs / name).mkdir(parents=True)
    (runs / name / "eval.json").write_text(json.dumps(result))


def test_scores_read_the_eval_output():
    s = Scores.from_eval(_eval(walk=0.0031))
    assert (s.step, s.seen_psnr, s.unseen_psnr) == (2770, 34.0, 30.0)
    assert (s.seen_iou, s.unseen_iou, s.seen_holes, s.unseen_holes, s.walk_holes) == (0.981, 0.965, 0.002, 0.004, 0.0031)
    assert Scores.from_eval(_eval(walk=None)).walk_holes is None


def test_an_output_at_the_wrong_scale_or_without_unseen_views_is_refused():
    with pytest.raises(ValueError, match=r"eval\.json: expected an eval at --scale 2, found scale 1"):
        Scores.from_eval(_eval(scale=1), source="eval.json")
    broken = _eval()
    broken["unseen_psnr"] = None  # a scene without unseen views
    with pytest.raises(ValueError, match="not an `eval --json` output"):
        Scores.from_eval(broken)


@pytest.mark.parametrize("field,value,target,ok", [
    ("seen_iou", 0.97, "iou", True), ("seen_iou", 0.9699, "iou", False),
    ("unseen_iou", 0.93, "iou", True), ("unseen_iou", 0.9299, "iou", False),
    ("seen_holes", 0.005, "holes", True), ("seen_holes", 0.0051, "holes", False),
    ("unseen_holes", 0.005, "holes", True), ("unseen_holes", 0.0051, "holes", False),
    ("unseen_psnr", 27.5, "unseen_psnr", True), ("unseen_psnr", 27.49, "unseen_psnr", False),
])
def test_each_target_flips_at_its_boundary(field, value, target, ok):
    base = dict(step=1, seen_psnr=34.0, unseen_psnr=30.0, seen_iou=0.98, unseen_iou=0.96, seen_holes=0.001,
                unseen_holes=0.001, walk_holes=None)
    base[field] = value
    v = verdict(Scores(**base), tight_unseen=29.0)
    assert v[target] is ok
    assert all(v[k] for k in v if k != target)


def test_without_a_tight_run_the_psnr_target_is_not_scored():
    s = Scores.from_eval(_eval())
    assert verdict(s, None)["unseen_psnr"] is None
    assert tight_verdict(s, None) is None
    assert tight_verdict(s, (34.19, 29.81)) is True
    assert tight_verdict(s, (34.21, 30.0)) is False


def test_collect_holds_each_garment_against_the_tight_run_of_its_own_seed(tmp_path):
    _write(tmp_path, "garment_s0", _eval(seen=(36.0, 0.98, 0.0), unseen=(29.3, 0.97, 0.0), walk=None))
    # the tight check against before reads the x1 eval: at x2 the same run scores 2-2.5 dB more
    (tmp_path / "garment_s0" / "eval_x1.json").write_text(
        json.dumps(_eval(seen=(32.4, 0.97, 0.0), unseen=(29.2, 0.96, 0.0), walk=None, scale=1)))
    _write(tmp_path, "garment_s1", _eval(seen=(32.1, 0.98, 0.0), unseen=(31.6, 0.97, 0.0), walk=None))
    _write(tmp_path, "coat_s0", _eval(unseen=(28.0, 0.96, 0.004)))
    _write(tmp_path, "coat_s1", _eval(unseen=(30.0, 0.96, 0.006)))
    _write(tmp_path, "coat_s1_II", _eval(unseen=(30.2, 0.96, 0.004)))
    (tmp_path / "skirt_s0").mkdir()  # trained, not evaluated yet: left out
    rows, tight = collect(tmp_path, ["coat", "skirt"], [0, 1], {0: (32.41, 29.26)})
    assert [r["run"] for r in rows] == ["coat_s0", "coat_s1", "coat_s1_II"]
    by = {r["run"]: r for r in rows}
    assert by["coat_s0"]["tight_unseen"] == 29.3 and by["coat_s0"]["verdict"]["unseen_psnr"] is True  # -1.3 dB
    assert by["coat_s1"]["tight_unseen"] == 31.6 and by["coat_s1"]["verdict"]["unseen_psnr"] is False  # -1.6 dB
    assert by["coat_s1"]["verdict"]["holes"] is False and by["coat_s1_II"]["verdict"]["holes"] is True
    assert [(t["run"], t["ok"]) for t in tight] == [("garment_s0", True), ("garment_s1", None)]
    md = table(rows)
    assert "| coat_s1 | 2770 | 34.00 / 30.00 | 31.60 (-1.60) | 0.9810 / 0.9600 | 0.20 % / 0.60 % | 0.30 % " \
           "| yes | **no** | **no** |" in md
    assert "| garment_s0 | 2770 | 32.40 / 29.20 | 32.41 / 29.26 | yes |" in tight_table(tight)


def test_an_unreadable_eval_file_names_itself(tmp_path):
    (tmp_path / "dress_s0").mkdir()
    (tmp_path / "dress_s0" / "eval.json").write_text("wrote runs/x/error_vs_time.png\n{")
    with pytest.raises(ValueError, match=r"dress_s0/eval\.json: not JSON"):
        collect(tmp_path, ["dress"], [0], {})


def test_tight_before_parses_and_names_a_bad_item():
    assert parse_before(["0:32.41/29.26", "2:32.33/28.85"]) == {0: (32.41, 29.26), 2: (32.33, 28.85)}
    with pytest.raises(ValueError, match=r"--tight-before '0-32\.41': expected SEED:SEEN/UNSEEN"):
        parse_before(["0-32.41"])
