"""What the garment layer's volume hint reads from scenes (``garment_layer.frame_hint_evidence``
per sampled frame, ``hint_from_evidence`` for the scene: ``volume_hint_from_masks`` in two parts): one row per scene with each sampled frame's
evidence -- ``C0.28`` cloth reaching 0.28 m below the fitted body's crotch, ``t0.06`` testable
(the body leaves a gap between its legs) but no cloth (a covered run only 0.06 m long), ``-``
nothing to test; then after ``/`` the legs (``frame_leg_evidence``): ``W5.6`` wide trouser legs
standing out 5.6 cm at the hem, ``l`` testable but not wide, ``-`` nothing to test; then after a
second ``/`` the torso (``frame_torso_evidence``): ``T2.4`` the mask standing out 2.4 cm past the
torso's sides, ``-`` nothing to test; then after a third ``/`` the flaps (``frame_flap_evidence``):
``L12.0`` / ``R12.0`` a flap standing out 12 cm at the body's left / right, ``f`` testable but no
flap, ``-`` nothing to test -- and the hint (top and hem heights, standoff at the top,
flare, one tube or two, the scene's torso standoff) or none. This is what ``avatar.garment_layer=auto`` decides on.

    OMP_NUM_THREADS=1 python benchmarks/garment_hint.py "synthetic:seed=0,clothing=skirt" \\
        "synthetic:seed=0" path/to/prepared_scene ...
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from reconstruct.avatar.garment_layer import (build_garment_layer, hint_from_evidence, scene_hint_evidence,  # noqa: E402
                                              torso_standoff)
from reconstruct.data.load import load_scene  # noqa: E402


def evidence_row(spec: str) -> str:
    scene = load_scene(spec, progress=False)
    body = scene.body_model()
    evidence = scene_hint_evidence(body, scene.frames)
    gap = lambda e: f"C{e.drop:.2f}" if e.cloth else f"t{e.drop:.2f}" if e.testable else "-"  # noqa: E731
    legs = lambda g: "-" if g is None or not g.testable else f"W{100 * g.flare:.1f}" if g.wide else "l"  # noqa: E731
    torso = lambda t: "-" if t is None or not t.testable else f"T{100 * t.standoff:.1f}"  # noqa: E731
    flaps = lambda f: ("-" if f is None or not f.testable else "".join(  # noqa: E731
        f"{n}{100 * v[0]:.1f}" for n, v in (("L", f.left), ("R", f.right)) if v is not None) or "f")
    marks = [f"{gap(e)}/{legs(e.legs)}/{torso(e.torso)}/{flaps(e.flaps)}" for e in evidence]
    hint = hint_from_evidence(body, evidence)
    ts = torso_standoff(evidence)
    said = "none" if hint is None else (f"{'two legs, ' if hint.two_legs else ''}top {hint.top_z:+.3f} m, "
                                        f"hem {hint.hem_z:+.3f} m, standoff {100 * hint.standoff_top:.1f} cm, "
                                        f"flare {100 * hint.standoff_hem:.1f} cm, "
                                        + "".join(f"{n} side {100 * v:.1f} cm, " for n, v in
                                                  (("left", hint.side_left), ("right", hint.side_right)) if v > 0)
                                        + f"{build_garment_layer(body, hint).num_gaussians:,} Gaussians")
    said += "" if ts is None else f" (torso {100 * ts:.1f} cm)"
    return f"| {spec} | {len(scene.frames)} | {' '.join(marks)} | {said} |"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", help="scene specs or folders")
    args = ap.parse_args(argv)
    print("| scene | frames | evidence per sampled frame | hint |\n|---|---|---|---|")
    for spec in args.scenes:
        print(evidence_row(spec), flush=True)


if __name__ == "__main__":
    main()
