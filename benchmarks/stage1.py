"""Stage I step time and where it goes, on the default synthetic scene, side by side for the
paper's / earlier defaults (``Stage1Config.paper()``: 9,832 isotropic Gaussians of a 128^2 map,
each decoded every step) and the current defaults (discs on a 256^2 map decoded at 128^2, only
what faces the step's camera decoded), plus each at the other map size.

Each configuration runs in its own process (thread settings must be fixed before torch loads):
    python benchmarks/stage1.py [--steps 20] [--threads 1] [--size 512] [--configs paper,default,...]
prints ms per step for LBS (+ the facing test), decoder forward (sampling S, the MLP, the
interpolation to the Gaussians), rasterizer forward (projection and kernel), losses, backward,
Adam; Gaussians decoded per step; steps per second and Gaussian-steps per second (Gaussians in the
avatar x steps per second); and the trainer's own step (``Trainer.step``, everything it does:
logging, the seen flags, densification bookkeeping) timed over the same number of steps after the
pieces. Configurations are run in turn, ``--rounds`` times each, interleaved (A B A B) so that a
change of load on a shared machine hits both.

The ``loose-*`` configurations train the wide-trousers scene (``clothing=wide_trousers``) with the
current defaults: without the garment layer (``loose-off``), with its rows every 2 cm (the
layer before, ``loose-2cm``), every 1.4 cm (the default before, ``loose-1.4cm``) and every 1 cm
(``loose-1cm``), every 7 mm decoded at every Gaussian (``loose-7mm``) or at every other row and
column (``loose-7mm-every2``: the decoder cost of 1.4 cm, ``AvatarConfig.garment_decode_every``), and every
1.4 cm or 1 cm decoded at every other row and column (``loose-1.4cm-every2``, ``loose-1cm-every2``;
``loose-1cm-every2`` is today's default layer, which ``coat`` and ``dress`` use); what the layer
adds is its Gaussians, the alpha-against-mask loss, the spacing regulariser over its grid edges
and its learned skinning with that prior (all in the pieces above, as in ``GivenViewStep``):
    python benchmarks/stage1.py --configs loose-off,loose-2cm,loose-1.4cm,loose-1cm,loose-7mm,loose-7mm-every2 --rounds 2
    python benchmarks/stage1.py --configs loose-off,loose-1.4cm,loose-1.4cm-every2,loose-1cm-every2 --rounds 2
and the layer's cover prior (``train/layer_cover.py``; in "losses") against none:
    python benchmarks/stage1.py --configs loose-1.4cm,loose-nocover --rounds 2
and, on the coat scene, the layer kept clear of the posed body (``avatar/layer_clearance.py``; in
"pose", which moves the decoded Gaussians by their LBS matrices) against not:
    python benchmarks/stage1.py --configs coat,coat-noclear --rounds 2
and what the layer costs on the coat and the dress scenes (the chest-high layers) against the same
scene without it:
    python benchmarks/stage1.py --configs coat-off,coat,dress-off,dress --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CONFIGS = {  # name -> (Stage1Config constructor, avatar overrides, the scene's clothing)
    "paper": ("paper", {}, None),
    "paper-256": ("paper", {"gaussian_resolution": 256}, None),
    "default": ("default", {}, None),
    "default-128": ("default", {"gaussian_resolution": 128}, None),
    "default-nocull": ("default", {}, None),
    "loose-off": ("default", {"garment_layer": "off"}, "wide_trousers"),
    "loose-2cm": ("default", {"garment_layer_step": 0.02, "garment_decode_every": 1}, "wide_trousers"),
    "loose-1.4cm": ("default", {"garment_layer_step": 0.014, "garment_decode_every": 1}, "wide_trousers"),
    "loose-1cm": ("default", {"garment_layer_step": 0.010, "garment_decode_every": 1}, "wide_trousers"),
    # Gaussians every 7 mm, decoded at every one (full) or every other row and column (layer_nodes.py)
    "loose-7mm": ("default", {"garment_layer_step": 0.007, "garment_decode_every": 1}, "wide_trousers"),
    "loose-7mm-every2": ("default", {"garment_layer_step": 0.007, "garment_decode_every": 2}, "wide_trousers"),
    "loose-1.4cm-every2": ("default", {"garment_layer_step": 0.014, "garment_decode_every": 2}, "wide_trousers"),
    "loose-1cm-every2": ("default", {"garment_layer_step": 0.010, "garment_decode_every": 2}, "wide_trousers"),
    "loose-nocover": ("default", {}, "wide_trousers"),  # the layer without its cover prior
    "coat": ("default", {}, "coat"),  # the layer kept clear of the posed body (the default)
    "coat-noclear": ("default", {"garment_clearance": 0.0}, "coat"),
    "coat-off": ("default", {"garment_layer": "off"}, "coat"),  # the coat scene without a layer
    "dress": ("default", {}, "dress"),
    "dress-off": ("default", {"garment_layer": "off"}, "dress"),
}


def child(cfg: dict) -> dict:
    sys.path.insert(0, str(ROOT))
    import torch

    torch.set_num_threads(cfg["threads"])
    from reconstruct import config as config_layer
    from reconstruct.data.load import load_scene
    from reconstruct.train import losses as L
    from reconstruct.train.config import Stage1Config
    from reconstruct.train.render import render_avatar
    from reconstruct.train.trainer import Trainer
    from reconstruct.avatar.garment_layer import neighbour_strain
    from reconstruct.train.layer_cover import view_cover_term

    kind, avatar, clothing = CONFIGS[cfg["name"]]
    base = Stage1Config.paper() if kind == "paper" else Stage1Config()
    over = {"eval_every_seconds": 1e9}
    if avatar:
        over["avatar"] = avatar
    if cfg["name"].endswith("nocull"):
        over["cull_backfacing"] = None
    if cfg["name"].endswith("nocover"):
        over["lambda_layer_cover"] = 0.0
    c = config_layer.with_overrides(base, over)
    spec = f"synthetic:seed=0,size={cfg['size']}" + (f",clothing={clothing}" if clothing else "")
    scene = load_scene(spec, progress=False)
    s = Trainer(scene, c)
    for _ in range(3):
        s.step()
    parts: dict[str, float] = {}

    def timed(name, fn):
        t = time.perf_counter()
        out = fn()
        parts[name] = parts.get(name, 0.0) + time.perf_counter() - t
        return out

    n = cfg["steps"]
    model = s.model
    decoded = 0
    t_all = time.perf_counter()
    for _ in range(n):  # the body of GivenViewStep, timed piece by piece
        i = s.next_frame()
        tgt = s.data.targets[i]

        def lbs():
            M = model.lbs_matrices(s.state.frame_transforms(i))
            idx = None if c.cull_backfacing is None else model.facing(M, tgt.camera.center, c.cull_backfacing)
            return M, idx

        M, idx = timed("lbs", lbs)
        decoded += model.num_gaussians if idx is None else len(idx)
        canon = timed("decoder", lambda: model.canonical(index=idx))
        posed = timed("pose", lambda: model.pose_with(canon, M if idx is None else M[idx], model.clearance_matrices(M),
                                                      model.layer_stretch_of(M)))
        r = timed("raster fwd", lambda: render_avatar(posed, tgt.camera, s.background, normals=True, first_hit=True))

        def loss_fn():
            loss = (0.8 * L.mse(r.rgb, tgt.image) + 0.2 * L.ssim_loss(r.rgb, tgt.image)
                    + 0.8 * L.mse(r.normal, tgt.normal) + 0.85 * L.mean_square(canon.offsets_raw)
                    + 0.03 * L.mean_square(canon.scales) + L.mean_square(canon.features))
            if model.num_layer:  # the garment layer's terms, as GivenViewStep adds them
                edges, rest = model.layer_edge_rows(idx)
                loss = loss + c.lambda_alpha * L.mse(r.alpha, tgt.mask) + c.lambda_layer_spacing * neighbour_strain(
                    canon.means, edges, rest)
                if c.lr_layer_skinning > 0:
                    loss = loss + c.lambda_layer_skinning * model.layer_skinning_prior()
                if c.lambda_layer_cover:
                    cover = view_cover_term(model, posed.means, idx, tgt.camera, tgt.inner_mask(c.layer_cover_inset))
                    loss = loss if cover is None else loss + c.lambda_layer_cover * cover
            return loss

        loss = timed("losses", loss_fn)
        s.optimizer.zero_grad(set_to_none=True)
        timed("backward", loss.backward)
        timed("adam", s.optimizer.step)
    total = time.perf_counter() - t_all
    t_trainer = time.perf_counter()
    for _ in range(n):
        s.step()
    trainer_ms = 1000 * (time.perf_counter() - t_trainer) / n
    return {**cfg, "gaussians": model.num_gaussians, "layer": model.num_layer, "nodes": model.num_nodes,
            "decoded": decoded / n, "ms": {k: 1000 * v / n for k, v in parts.items()}, "step_ms": 1000 * total / n,
            "it_per_s": n / total, "trainer_ms": trainer_ms}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--configs", default="paper,default,paper-256,default-128")
    ap.add_argument("--json", default=None, help="also write the rows to this file")
    ap.add_argument("--child", default=None)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    names = args.configs.split(",")
    for name in names:
        if name not in CONFIGS:
            raise SystemExit(f"unknown configuration {name!r}: one of {', '.join(CONFIGS)}")
    print(f"load average before: {os.getloadavg()[0]:.2f}; {args.threads} thread(s), OMP_WAIT_POLICY=PASSIVE")
    rows: dict[str, list[dict]] = {n: [] for n in names}
    failed: set[str] = set()
    for _ in range(args.rounds):
        for name in names:
            cfg = {"name": name, "threads": args.threads, "size": args.size, "steps": args.steps}
            env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": str(args.threads)}
            out = subprocess.run([sys.executable, __file__, "--child", json.dumps(cfg)], env=env, capture_output=True,
                                 text=True)
            if out.returncode != 0:
                print(out.stderr[-2000:])
                failed.add(name)
                continue
            rows[name].append(json.loads(out.stdout.strip().splitlines()[-1]))
    keys = ["lbs", "decoder", "pose", "raster fwd", "losses", "backward", "adam"]
    print(f"{'config':<15} {'N':>6} {'layer':>6} {'decoded':>7} " + " ".join(f"{k:>10}" for k in keys)
          + f" {'step ms':>8} {'it/s':>6} {'Gauss-steps/s':>13} {'Trainer.step ms':>15}")
    summary = {}
    for name, rs in rows.items():
        if not rs:
            continue
        best = min(rs, key=lambda r: r["step_ms"])  # the least disturbed round
        gsps = best["gaussians"] * best["it_per_s"]
        summary[name] = {**best, "gaussian_steps_per_s": gsps}
        print(f"{name:<15} {best['gaussians']:>6} {best['layer']:>6} {best['decoded']:>7.0f} "
              + " ".join(f"{best['ms'][k]:>10.1f}" for k in keys)
              + f" {best['step_ms']:>8.1f} {best['it_per_s']:>6.2f} {gsps:>13.0f}"
              + f" {min(r['trainer_ms'] for r in rs):>15.1f}")
    if "paper" in summary:
        ref = summary["paper"]["gaussian_steps_per_s"]
        print("Gaussian-steps/s relative to 'paper': "
              + ", ".join(f"{n} {v['gaussian_steps_per_s'] / ref:.2f}x" for n, v in summary.items()))
    print(f"load average after: {os.getloadavg()[0]:.2f}  (image {args.size}^2, body crop per frame)")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1))
    if failed:  # a configuration that no longer runs must not pass as a shorter table
        raise SystemExit(f"failed: {', '.join(n for n in names if n in failed)} (errors above)")


if __name__ == "__main__":
    main()
