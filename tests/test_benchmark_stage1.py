"""benchmarks/stage1.py still runs what it times: the body of a Stage I step on a loose-clothing
scene with its garment layer (a configuration that breaks must fail, not drop out of the table)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_stage1", ROOT / "benchmarks" / "stage1.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_step_benchmark_times_a_layered_avatar_decoded_at_every_gaussian_or_at_its_nodes():
    bench = _bench()
    every1, every2 = (bench.child({"name": name, "threads": 1, "size": 96, "steps": 1})
                      for name in ("loose-1.4cm", "loose-1.4cm-every2"))
    assert every1["layer"] == every2["layer"] > 0 and every1["gaussians"] == every2["gaussians"]
    # every layer Gaussian is a decoder node, or about one in four of them is
    assert every1["nodes"] - every2["nodes"] > 0.6 * every1["layer"]
    for out in (every1, every2):
        for key in ("lbs", "decoder", "pose", "raster fwd", "losses", "backward", "adam"):
            assert out["ms"][key] > 0, key
        assert out["step_ms"] > 0 and out["trainer_ms"] > 0
