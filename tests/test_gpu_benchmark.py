"""benchmarks/gpu.py's report: rates from the training records, the last evaluation, the tables."""

import importlib.util
import json
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location("gpu_bench", Path(__file__).resolve().parents[1] / "benchmarks" / "gpu.py")
gpu = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gpu)


def _write_run(run: Path, rate: float, warmup_s: float = 30.0) -> None:
    """A Stage I metrics log: a training record every 25 steps, the first 25 of them slow (warm-up:
    ``warmup_s``), then ``rate`` steps/s; evaluations at 0 and at the end; then a Stage II record."""
    run.mkdir(parents=True)
    rows = [{"kind": "eval", "step": 0, "elapsed": 1.0, "stage": 1, "seen_psnr": 20.0, "unseen_psnr": 19.0}]
    for k in range(1, 21):
        step = 25 * k
        rows.append({"kind": "train", "step": step, "stage_step": step, "stage": 1, "gaussians_decoded": 1234,
                     "elapsed": 1.0 + warmup_s if k == 1 else 1.0 + 2 * warmup_s + (step - 50) / rate})
    rows.append({"kind": "eval", "step": 500, "elapsed": 80.0, "stage": 1, "seen_psnr": 31.5, "unseen_psnr": 28.25})
    rows.append({"kind": "train", "step": 525, "stage_step": 25, "stage": 2, "elapsed": 90.0})
    (run / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")


def test_stage_summary_rate_skips_the_warm_up_and_takes_the_last_evaluation(tmp_path):
    _write_run(tmp_path / "run", rate=20.0)
    s = gpu._stage_summary(tmp_path / "run", 1)
    assert s["steps"] == 500
    assert s["steps_per_s"] == pytest.approx(20.0)  # the slow first record is left out
    assert (s["seen_psnr"], s["unseen_psnr"]) == (31.5, 28.25)
    assert s["gaussians"] == 1234
    assert len(s["curve"]) == 2
    assert gpu._stage_summary(tmp_path / "run", 2)["steps"] == 25  # a stage's own records only
    assert gpu._stage_summary(tmp_path / "missing", 1) == {"steps": 0}


def test_report_tables_and_plot(tmp_path):
    _write_run(tmp_path / "runs" / "stage1_256", rate=10.0)
    (tmp_path / "stage1_256.json").write_text(json.dumps({"rc": 0, "wall_s": 95.0, "peak_gb": 0.5, "reserved_gb": 1.0}))
    (tmp_path / "raster.json").write_text(json.dumps([{"backend": "gsplat", "gaussians": 65536, "size": 512,
                                                        "fwd_ms": 1.5, "fwd_bwd_ms": 2.5}]))
    (tmp_path / "tests.log").write_text("....\ngsplat vs cpu image: 5.4e-07\nnoise\n54 passed in 8s\n")
    gpu.write_report(tmp_path, {"env": {"rc": 0, "s": 1.0}})
    text = (tmp_path / "report.md").read_text()
    assert "| stage1_256 | 1 | 500 | 10.00 | 100 | 1234 | 31.50 / 28.25 | 0.50 / 1.00 | 95 (rc 0) |" in text
    assert "| gsplat | 65536 | 512² | 1.50 | 2.50 |" in text
    assert "gsplat vs cpu image: 5.4e-07" in text and "noise" not in text
    assert (tmp_path / "stage1_psnr_vs_time.png").stat().st_size > 1000
