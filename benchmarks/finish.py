"""Time Stage I's finish on trained runs: the whole finish (the seen recount, the garment layer's
per-frame tests, the fills), and the layer's per-frame tests read in one pass over the training
frames (``layer_training_views``, what the finish does) against one pass per test (faced a camera,
seen from inside, off the person: what it did before). Nothing in the run folders is changed.

    OMP_NUM_THREADS=1 python benchmarks/finish.py RUN [RUN ...] [--repeat N]

Prints a table of seconds, the best of ``--repeat`` (default 2) for each.
"""

from __future__ import annotations

import sys
import time


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def time_finish(run: str, repeat: int = 2) -> dict:
    """{"run", "frames", "layer", "finish_s", "one_pass_s", "three_passes_s"} for ``run`` (the
    layer times are None without a garment layer). Each finish starts from the checkpoint again."""
    import torch

    from reconstruct.run_folder import RunFolder
    from reconstruct.train.unseen_fill import (layer_faced_training, layer_off_person, layer_seen_inside,
                                               layer_training_views)

    folder = RunFolder(run)
    trainer = folder.resume()
    scene = trainer.scene

    def finish() -> None:
        t = folder.resume(scene)  # the checkpoint's state, not one already finished
        t.plan.finish(t)

    out = {"run": run, "frames": len(trainer.data.frames), "layer": trainer.model.num_layer,
           "finish_s": _best(finish, repeat), "one_pass_s": None, "three_passes_s": None}
    if trainer.model.num_layer:
        st, data = trainer.state, trainer.data
        with torch.no_grad():
            out["one_pass_s"] = _best(lambda: layer_training_views(st, data, seen_inside=True, off_person=True),
                                      repeat)
            out["three_passes_s"] = _best(lambda: (layer_faced_training(st, data), layer_seen_inside(st, data),
                                                   layer_off_person(st, data)), repeat)
    return out


def main(argv: list[str]) -> int:
    runs, repeat = [], 2
    it = iter(argv)
    for a in it:
        if a == "--repeat":
            repeat = int(next(it, "2"))
        else:
            runs.append(a)
    if not runs or repeat < 1:
        print(__doc__)
        return 2
    import torch

    torch.set_num_threads(1)
    print("| run | frames | layer Gaussians | finish, s | layer tests, one pass, s | layer tests, three passes, s |")
    print("|---|---|---|---|---|---|")
    fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
    for run in runs:
        r = time_finish(run, repeat)
        print(f"| {r['run']} | {r['frames']} | {r['layer']} | {r['finish_s']:.1f} | {fmt(r['one_pass_s'])} | "
              f"{fmt(r['three_passes_s'])} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
