"""Stage I step time and where it goes, on the default synthetic scene.

Each configuration runs in its own process (OpenMP settings must be fixed before torch loads):
    python benchmarks/stage1.py [--steps 20] [--gaussian-res 128] [--size 512] [--quick]
prints a table: ms per step for decoder, LBS, rasterizer forward, losses, backward (rasterizer +
decoder), Adam, and steps per second, for torch threads 1 and 2 and OMP_WAIT_POLICY active/passive.
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


def child(cfg: dict) -> dict:
    sys.path.insert(0, str(ROOT))
    import torch

    torch.set_num_threads(cfg["threads"])
    from reconstruct.avatar.config import AvatarConfig
    from reconstruct.data.load import load_scene
    from reconstruct.train import losses as L
    from reconstruct.train.config import Stage1Config
    from reconstruct.train.render import render_avatar
    from reconstruct.train.trainer import Trainer

    scene = load_scene(f"synthetic:seed=0,size={cfg['size']}", progress=False)
    s = Trainer(scene, Stage1Config(eval_every_seconds=1e9, avatar=AvatarConfig(gaussian_resolution=cfg["res"])))
    for _ in range(3):
        s.step()
    parts: dict[str, float] = {}

    def timed(name, fn):
        t = time.perf_counter()
        out = fn()
        parts[name] = parts.get(name, 0.0) + time.perf_counter() - t
        return out

    n = cfg["steps"]
    t_all = time.perf_counter()
    for _ in range(n):
        i = s.next_frame()
        tgt = s.data.targets[i]
        canon = timed("decoder", lambda: s.model.canonical())
        posed = timed("lbs", lambda: s.model.pose(canon, s.state.frame_transforms(i)))
        r = timed("raster fwd", lambda: render_avatar(posed, tgt.camera, s.background, normals=True, first_hit=True))

        def loss_fn():
            return (0.8 * L.mse(r.rgb, tgt.image) + 0.2 * L.ssim_loss(r.rgb, tgt.image)
                    + 0.8 * L.mse(r.normal, tgt.normal) + 0.85 * L.mean_square(canon.offsets_raw)
                    + 0.03 * L.mean_square(canon.scales) + L.mean_square(canon.features))

        loss = timed("losses", loss_fn)
        s.optimizer.zero_grad(set_to_none=True)
        timed("backward", loss.backward)
        timed("adam", s.optimizer.step)
    total = time.perf_counter() - t_all
    return {**cfg, "gaussians": s.model.num_gaussians, "ms": {k: 1000 * v / n for k, v in parts.items()},
            "step_ms": 1000 * total / n, "it_per_s": n / total}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--gaussian-res", type=int, default=128)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--quick", action="store_true", help="only 2 threads with passive OpenMP waiting")
    ap.add_argument("--child", default=None)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    configs = [(2, "PASSIVE")] if args.quick else [(1, "PASSIVE"), (2, "PASSIVE"), (1, "ACTIVE"), (2, "ACTIVE")]
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    rows = []
    for threads, policy in configs:
        cfg = {"threads": threads, "res": args.gaussian_res, "size": args.size, "steps": args.steps}
        env = {**os.environ, "OMP_WAIT_POLICY": policy}
        out = subprocess.run([sys.executable, __file__, "--child", json.dumps(cfg)], env=env, capture_output=True, text=True)
        if out.returncode != 0:
            print(out.stderr[-2000:])
            continue
        rows.append((policy, json.loads(out.stdout.strip().splitlines()[-1])))
    keys = ["decoder", "lbs", "raster fwd", "losses", "backward", "adam"]
    print(f"{'threads':>7} {'omp wait':>8} {'N':>6} " + " ".join(f"{k:>10}" for k in keys) + f" {'step ms':>8} {'it/s':>6}")
    for policy, r in rows:
        print(f"{r['threads']:>7} {policy:>8} {r['gaussians']:>6} " + " ".join(f"{r['ms'][k]:>10.1f}" for k in keys)
              + f" {r['step_ms']:>8.1f} {r['it_per_s']:>6.2f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}  (image {args.size}^2, body crop per frame)")


if __name__ == "__main__":
    main()
