"""benchmarks/finish.py: times Stage I's finish on a run folder from its checkpoint each time,
leaves the folder as it was, and prints one table row per run (no layer columns without a layer)."""

import hashlib

from benchmarks.finish import main, time_finish
from tests.tiny_runs import train_tiny


def _digest(path) -> str:
    return hashlib.sha256((path / "checkpoint.pt").read_bytes()).hexdigest()


def test_times_the_finish_and_changes_nothing(tmp_path, capsys):
    run = train_tiny(tmp_path / "run", 3)
    before = _digest(run)
    r = time_finish(str(run), repeat=1)
    assert r["finish_s"] > 0 and r["frames"] > 0
    assert r["layer"] == 0 and r["one_pass_s"] is None and r["three_passes_s"] is None
    assert main([str(run), "--repeat", "1"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith(f"| {run} |")]
    assert len(rows) == 1 and rows[0].count("|") == 7 and rows[0].rstrip().endswith("| - | - |")
    assert _digest(run) == before
    assert main([]) == 2
