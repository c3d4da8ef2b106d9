"""Rasterizer benchmark: forward+backward time and peak memory of the backends on a body-like scene.

    python benchmarks/raster.py [--quick] [--out results.json]

Scene: N Gaussians on the closed surfaces of capsules forming a ~1.7 m figure, flat along the
surface normal and about as wide as their spacing, seen from ~3 m by a square camera whose
field of view frames the figure (it covers about 20 % of the image at alpha > 0.5).

Backends, all on the same float32 inputs:
- kernel: ``rasterization(backend="cpu")`` (compiled tiles + hand-written backward);
- torch:  ``rasterization(backend="torch")`` (the pure-torch reference compositor, autograd);
- gsplat: gsplat 1.5.3's pure-torch path (``_torch_impl``): its projection and its tile
  intersection, forward only (``_isect_tiles`` is a Python loop over the Gaussians); its
  ``_rasterize_to_pixels`` calls ``rasterize_to_indices_in_range``, a CUDA kernel, so that part
  cannot run on a CPU (calling it would also make gsplat attempt a CUDA build).

Each (configuration, backend) runs in its own subprocess; time is the median of several runs
after a warm-up (a single run, marked "x1", when one run takes more than a few seconds); memory is
the growth of the peak resident set (``resource.getrusage(...).ru_maxrss``) over the runs.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SLOW_S = 3.0  # one run longer than this: do not repeat it

CAPSULES = [  # (a, b, radius) in metres, Z up, A-pose
    ((0.0, 0.0, 0.95), (0.0, 0.0, 1.40), 0.16),    # torso
    ((0.0, 0.0, 1.55), (0.0, 0.0, 1.62), 0.10),    # head
    ((-0.1, 0.0, 0.08), (-0.1, 0.0, 0.88), 0.07),  # legs
    ((0.1, 0.0, 0.08), (0.1, 0.0, 0.88), 0.07),
    ((-0.2, 0.0, 1.38), (-0.45, 0.0, 0.85), 0.05),  # arms
    ((0.2, 0.0, 1.38), (0.45, 0.0, 0.85), 0.05),
]


def _capsule_samples(rng, n: int, a, b, radius: float):
    """n points spread uniformly over a capsule's surface, with their outward normals."""
    import numpy as np

    a, b = np.asarray(a, float), np.asarray(b, float)
    length = np.linalg.norm(b - a)
    axis = (b - a) / length
    side_area, cap_area = 2 * math.pi * radius * length, 4 * math.pi * radius ** 2
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radial = direction - (direction @ axis)[:, None] * axis
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    on_side = (rng.random(n) < side_area / (side_area + cap_area))[:, None]
    centre = np.where(on_side, a + rng.random((n, 1)) * (b - a),
                      np.where((direction @ axis)[:, None] > 0, b, a))
    normal = np.where(on_side, radial, direction)
    return centre + radius * normal, normal


def body_scene(n: int, channels: int, seed: int = 0) -> dict:
    """Float32 Gaussians on the capsule figure; scales ~ the sample spacing, 0.3x along the normal."""
    import numpy as np
    import torch

    from reconstruct.gaussians import quats_aligning_z

    rng = np.random.default_rng(seed)
    areas = np.array([2 * math.pi * r * math.dist(a, b) + 4 * math.pi * r * r for a, b, r in CAPSULES])
    counts = np.floor(n * areas / areas.sum()).astype(int)
    counts[0] += n - counts.sum()
    samples = [_capsule_samples(rng, k, a, b, r) for (a, b, r), k in zip(CAPSULES, counts)]
    points = np.concatenate([p for p, _ in samples])
    normals = np.concatenate([q for _, q in samples])
    spacing = math.sqrt(areas.sum() / n)
    quats = quats_aligning_z(normals)
    scales = np.array([1.0, 1.0, 0.3]) * spacing * rng.uniform(0.7, 1.3, size=(n, 1))
    as_tensor = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    return {"means": as_tensor(points), "quats": as_tensor(quats), "scales": as_tensor(scales),
            "opacities": as_tensor(rng.uniform(0.5, 1.0, n)), "features": as_tensor(rng.random((n, channels)))}


def body_camera(size: int):
    from reconstruct.camera import Camera

    return Camera.look_at((0.3, -3.0, 1.0), (0.0, 0.0, 0.85), width=size, height=size, fov_y_deg=36)


# ------------------------------------------------------------------------------------------------
# one configuration (child process)
# ------------------------------------------------------------------------------------------------

def _ours(backend: str, scene: dict, camera):
    """A forward+backward step of ``rasterization`` with the given backend."""
    from reconstruct.raster import rasterization

    leaves = {k: v.clone().requires_grad_() for k, v in scene.items()}

    def step():
        out = rasterization(*leaves.values(), camera, backend=backend)
        (out.image.sum() + out.depth.sum() + out.alpha.sum()).backward()
        for leaf in leaves.values():
            leaf.grad = None
        return float((out.alpha > 0.5).float().mean())

    return step


def _gsplat_torch_path(scene: dict, camera):
    """gsplat's pure-torch projection and tile intersection (forward only)."""
    import torch
    from gsplat.cuda import _torch_impl as impl

    viewmat = torch.tensor(camera.viewmat, dtype=torch.float32)[None]
    K = torch.tensor(camera.K, dtype=torch.float32)[None]
    tiles_x, tiles_y = math.ceil(camera.width / 16), math.ceil(camera.height / 16)

    def step():
        with torch.no_grad():
            covars, _ = impl._quat_scale_to_covar_preci(scene["quats"], scene["scales"], compute_preci=False)
            radii, means2d, depths, conics, _ = impl._fully_fused_projection(
                scene["means"], covars, viewmat, K, camera.width, camera.height, eps2d=0.3)
            impl._isect_tiles(means2d, radii, depths, 16, tiles_x, tiles_y)
        return None

    return step


def _time(step, warmup: int, runs: int) -> tuple[float, int, float | None]:
    """Median milliseconds over ``runs`` after ``warmup`` calls (one call only if it is slow)."""
    t0 = time.perf_counter()
    coverage = step()
    first = time.perf_counter() - t0
    if first > SLOW_S:
        return 1000 * first, 1, coverage
    for _ in range(warmup - 1):
        step()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times), runs, coverage


def run_child(config: dict) -> dict:
    import torch

    torch.set_num_threads(config["threads"])
    scene = body_scene(config["n"], config["channels"])
    camera = body_camera(config["size"])
    backend = config["backend"]
    if backend == "kernel":
        from reconstruct.raster import cpu_backend

        cpu_backend.load_extension()  # a build, if needed, is not part of the measurement
        step, warmup, runs = _ours("cpu", scene, camera), 2, 7
    elif backend == "torch":
        step, warmup, runs = _ours("torch", scene, camera), 1, 3
    else:
        step, warmup, runs = _gsplat_torch_path(scene, camera), 1, 3
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    ms, n_runs, coverage = _time(step, warmup, runs)
    rss_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return dict(config, ms=ms, runs=n_runs, peak_mb=(rss_after - rss_before) / 1024, coverage=coverage)


# ------------------------------------------------------------------------------------------------
# driver
# ------------------------------------------------------------------------------------------------

def configurations(quick: bool) -> list[dict]:
    if quick:
        grid = itertools.product([16384], [256, 512], [3], [2])
    else:
        grid = itertools.product([16384, 65536], [256, 512], [3, 7], [1, 2])
    return [{"n": n, "size": s, "channels": c, "threads": t} for n, s, c, t in grid]


def measure(config: dict, backend: str, passive: bool) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS=str(config["threads"]), PYTHONPATH=str(ROOT))
    if passive:
        env["OMP_WAIT_POLICY"] = "PASSIVE"
    child = dict(config, backend=backend)
    proc = subprocess.run([sys.executable, __file__, "--child", json.dumps(child)], capture_output=True, text=True,
                          env=env, cwd=ROOT)
    if proc.returncode != 0:
        return dict(child, error=proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "failed")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _cell(result: dict) -> str:
    if "error" in result:
        return "error"
    mark = " x1" if result["runs"] == 1 else ""
    return f"{result['ms']:9.1f}{mark}"


HEADER = (f"{'N':>6} {'image':>7} {'C':>2} {'thr':>3} | {'kernel ms':>9} {'MB':>5} | {'torch ms':>12} {'MB':>5} "
          f"{'torch/kern':>10} | {'gsplat-py ms':>12} {'gs/kern':>7}")


def format_row(config: dict, res: dict) -> str:
    k, t, g = res["kernel"], res["torch"], res["gsplat"]

    def ratio(other: dict) -> str:
        return f"{other['ms'] / k['ms']:.1f}x" if "error" not in other and "error" not in k else "-"

    mb = {name: r.get("peak_mb", float("nan")) for name, r in res.items()}
    return (f"{config['n']:>6} {config['size']:>4}^2 {config['channels']:>2} {config['threads']:>3} | "
            f"{_cell(k):>9} {mb['kernel']:5.0f} | {_cell(t):>12} {mb['torch']:5.0f} "
            f"{ratio(t):>10} | {_cell(g):>12} {ratio(g):>7}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="16k Gaussians, C=3, 2 threads, 256^2 and 512^2 only")
    parser.add_argument("--out", type=Path, help="write all results as JSON here")
    parser.add_argument("--passive", action="store_true",
                        help="OMP_WAIT_POLICY=PASSIVE in the children: idle OpenMP threads sleep instead of "
                             "spinning (much faster when other processes compete for the cores)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(run_child(json.loads(args.child))))
        return

    load_before = os.getloadavg()
    policy = "PASSIVE" if args.passive else os.environ.get("OMP_WAIT_POLICY", "default")
    print(f"load average before: {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}; "
          f"cpus: {os.cpu_count()}; OMP_WAIT_POLICY={policy}; "
          f"memory = growth of ru_maxrss in a subprocess per cell (psutil not used)")
    print(HEADER)
    print("-" * len(HEADER), flush=True)
    rows = []
    for config in configurations(args.quick):
        rows.append((config, {b: measure(config, b, args.passive) for b in ("kernel", "torch", "gsplat")}))
        print(format_row(*rows[-1]), flush=True)
    coverage = rows[0][1]["kernel"].get("coverage")
    if coverage:
        print(f"body-like scene: the figure covers {100 * coverage:.0f}% of the image (alpha > 0.5)")
    print("gsplat-py = gsplat 1.5.3 _torch_impl projection + _isect_tiles, forward only (its _rasterize_to_pixels "
          "calls rasterize_to_indices_in_range, a CUDA kernel, so it cannot run here); x1 = a single run")
    load_after = os.getloadavg()
    print(f"load average after: {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}")
    if args.out:
        results = [dict(config, **{b: r for b, r in res.items()}) for config, res in rows]
        args.out.write_text(json.dumps({"load_before": load_before, "load_after": load_after, "results": results},
                                       indent=2))


if __name__ == "__main__":
    main()
