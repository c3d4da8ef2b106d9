"""Frames per second of the splat renderer (offscreen EGL) by splat count, resolution and mode.

    .venv/bin/python benchmarks/renderer.py            # 16k, 65k, 262k splats at 512² and 1024², all modes
    .venv/bin/python benchmarks/renderer.py --quick    # fewer frames, 16k and 65k only

The splats are a body-like avatar (Gaussians on capsules, 1.7 m tall, scales matched to the
splat count so that the surface is covered about as densely as a trained avatar's) framed to
fill ~85% of the image height. Every timed frame turns the camera by 1° so the depth sort
really runs each frame. Columns (milliseconds, means over the timed frames):

- sort:  camera depth, culling and the 16-bit radix sort (CPU, numpy);
- upload: the per-frame write of the sorted ids (N x 4 bytes);
- draw:  instanced draw until ``ctx.finish()`` (llvmpipe renders on the CPU here);
- read:  readback of the float32 RGBA image;
- fps:   1000 / (sort + upload + draw), i.e. what a window would get without readback;
- fps+rb: including the readback, what an export gets.

The one-time data upload per snapshot (sanitize + pack + texture write) is printed per count.
The script also reports the machine load (``os.getloadavg``), because other processes share
the CPU with llvmpipe.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # first: this folder's renderer.py must not shadow the package

from reconstruct.camera import Camera  # noqa: E402
from reconstruct.snapshot import Snapshot  # noqa: E402

# ----------------------------------------------------------------------------- test scenes
# (name, start, end, radius, rgb front, rgb back); metres, Z up, facing -Y
_CAPSULES = [
    ("torso", (0.0, 0.0, 1.00), (0.0, 0.0, 1.36), 0.150, (0.80, 0.20, 0.20), (0.25, 0.30, 0.75)),
    ("pelvis", (0.0, 0.0, 0.92), (0.0, 0.0, 1.00), 0.140, (0.20, 0.25, 0.55), (0.20, 0.25, 0.55)),
    ("neck", (0.0, 0.0, 1.38), (0.0, 0.0, 1.48), 0.050, (0.90, 0.72, 0.60), (0.90, 0.72, 0.60)),
    ("head", (0.0, 0.0, 1.57), (0.0, 0.0, 1.60), 0.105, (0.92, 0.75, 0.62), (0.30, 0.20, 0.12)),
    ("upper_arm_l", (0.19, 0.0, 1.36), (0.33, 0.0, 1.12), 0.048, (0.80, 0.20, 0.20), (0.25, 0.30, 0.75)),
    ("fore_arm_l", (0.33, 0.0, 1.12), (0.45, 0.0, 0.90), 0.038, (0.90, 0.72, 0.60), (0.90, 0.72, 0.60)),
    ("upper_arm_r", (-0.19, 0.0, 1.36), (-0.33, 0.0, 1.12), 0.048, (0.80, 0.20, 0.20), (0.25, 0.30, 0.75)),
    ("fore_arm_r", (-0.33, 0.0, 1.12), (-0.45, 0.0, 0.90), 0.038, (0.90, 0.72, 0.60), (0.90, 0.72, 0.60)),
    ("thigh_l", (0.09, 0.0, 0.92), (0.11, 0.0, 0.50), 0.075, (0.20, 0.25, 0.55), (0.15, 0.15, 0.35)),
    ("shin_l", (0.11, 0.0, 0.50), (0.12, 0.0, 0.09), 0.052, (0.20, 0.25, 0.55), (0.15, 0.15, 0.35)),
    ("thigh_r", (-0.09, 0.0, 0.92), (-0.11, 0.0, 0.50), 0.075, (0.20, 0.25, 0.55), (0.15, 0.15, 0.35)),
    ("shin_r", (-0.11, 0.0, 0.50), (-0.12, 0.0, 0.09), 0.052, (0.20, 0.25, 0.55), (0.15, 0.15, 0.35)),
    ("foot_l", (0.12, 0.02, 0.045), (0.13, -0.14, 0.035), 0.040, (0.10, 0.10, 0.10), (0.10, 0.10, 0.10)),
    ("foot_r", (-0.12, 0.02, 0.045), (-0.13, -0.14, 0.035), 0.040, (0.10, 0.10, 0.10), (0.10, 0.10, 0.10)),
]
_JOINTS = {  # name: (position, parent)
    "pelvis": ((0.0, 0.0, 0.95), None), "spine": ((0.0, 0.0, 1.20), "pelvis"), "neck": ((0.0, 0.0, 1.42), "spine"),
    "head": ((0.0, 0.0, 1.60), "neck"),
    "shoulder_l": ((0.19, 0.0, 1.36), "neck"), "elbow_l": ((0.33, 0.0, 1.12), "shoulder_l"),
    "wrist_l": ((0.45, 0.0, 0.90), "elbow_l"),
    "shoulder_r": ((-0.19, 0.0, 1.36), "neck"), "elbow_r": ((-0.33, 0.0, 1.12), "shoulder_r"),
    "wrist_r": ((-0.45, 0.0, 0.90), "elbow_r"),
    "hip_l": ((0.09, 0.0, 0.92), "pelvis"), "knee_l": ((0.11, 0.0, 0.50), "hip_l"),
    "ankle_l": ((0.12, 0.0, 0.09), "knee_l"),
    "hip_r": ((-0.09, 0.0, 0.92), "pelvis"), "knee_r": ((-0.11, 0.0, 0.50), "hip_r"),
    "ankle_r": ((-0.12, 0.0, 0.09), "knee_r"),
}


def _quat_z_to(n: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """(w,x,y,z) quaternions rotating +Z onto the unit vectors ``n``, then twisted about them."""
    w = 1.0 + n[:, 2]
    q = np.stack([w, -n[:, 1], n[:, 0], np.zeros_like(w)], axis=1)
    flip = w < 1e-6
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    tw = np.stack([np.cos(twist / 2), np.zeros_like(twist), np.zeros_like(twist), np.sin(twist / 2)], axis=1)
    a, b = q, tw  # q * tw (twist about local z first)
    return np.stack([
        a[:, 0] * b[:, 0] - a[:, 1] * b[:, 1] - a[:, 2] * b[:, 2] - a[:, 3] * b[:, 3],
        a[:, 0] * b[:, 1] + a[:, 1] * b[:, 0] + a[:, 2] * b[:, 3] - a[:, 3] * b[:, 2],
        a[:, 0] * b[:, 2] - a[:, 1] * b[:, 3] + a[:, 2] * b[:, 0] + a[:, 3] * b[:, 1],
        a[:, 0] * b[:, 3] + a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1] + a[:, 3] * b[:, 0]], axis=1)


def body_like_snapshot(n: int, seed: int = 0, coverage: float = 1.0, version: int = 1) -> Snapshot:
    """``n`` flat Gaussians on the surface of a capsule body 1.7 m tall (Z up, facing -Y), coloured
    by part with a pattern that differs front and back; normals are the surface normals,
    visibility marks the front-facing ones (what a front training camera would see)."""
    rng = np.random.default_rng(seed)
    rad = np.array([c[3] for c in _CAPSULES])
    a = np.array([c[1] for c in _CAPSULES], np.float64)
    b = np.array([c[2] for c in _CAPSULES], np.float64)
    length = np.linalg.norm(b - a, axis=1)
    cyl_area = 2 * np.pi * rad * length
    cap_area = 4 * np.pi * rad ** 2
    area = cyl_area + cap_area
    part = rng.choice(len(_CAPSULES), size=n, p=area / area.sum())
    axis = (b - a) / np.maximum(length, 1e-9)[:, None]
    ref = np.where(np.abs(axis[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(axis, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(axis, e1)
    on_cyl = rng.random(n) < (cyl_area / area)[part]
    t = rng.random(n)
    th = rng.random(n) * 2 * np.pi
    normal = np.cos(th)[:, None] * e1[part] + np.sin(th)[:, None] * e2[part]
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    normal = np.where(on_cyl[:, None], normal, u)
    along = np.sum(u * axis[part], axis=1)
    centre = np.where(on_cyl[:, None], a[part] + t[:, None] * (b - a)[part],
                      np.where((along >= 0)[:, None], b[part], a[part]))
    means = centre + rad[part][:, None] * normal

    spacing = math.sqrt(area.sum() / n)
    tangent = spacing * coverage * rng.uniform(0.45, 0.8, size=(n, 2))
    scales = np.concatenate([tangent, spacing * 0.08 * np.ones((n, 1))], axis=1)
    quats = _quat_z_to(normal, rng.random(n) * 2 * np.pi)

    front = np.array([c[4] for c in _CAPSULES])[part]
    back = np.array([c[5] for c in _CAPSULES])[part]
    facing_front = normal[:, 1] < 0
    stripes = (np.floor(means[:, 2] / 0.06) % 2 == 0)[:, None]
    colors = np.where(facing_front[:, None], front, back) * np.where(stripes, 1.0, 0.75)
    colors = np.clip(colors + rng.normal(0, 0.02, size=colors.shape), 0, 1)
    opac = rng.uniform(0.85, 1.0, size=n)
    visibility = (normal[:, 1] < 0.15).astype(np.uint8)

    names = list(_JOINTS)
    joints = np.array([_JOINTS[k][0] for k in names], np.float32)
    parents = np.array([names.index(_JOINTS[k][1]) if _JOINTS[k][1] else -1 for k in names], np.int64)
    f32 = np.float32
    return Snapshot(means.astype(f32), scales.astype(f32), quats.astype(f32), colors.astype(f32), opac.astype(f32),
                    normal.astype(f32), visibility, version=version, joints=joints, joint_parents=parents)


def random_snapshot(n: int, seed: int = 0, center=(0.0, 0.0, 1.0), extent: float = 0.5,
                    scale_range=(0.004, 0.06), version: int = 1) -> Snapshot:
    """``n`` Gaussians with random means in a cube of half-size ``extent``, log-uniform anisotropic
    scales, random rotations, colours, normals and opacities in [0.05, 1]."""
    rng = np.random.default_rng(seed)
    means = np.asarray(center) + rng.uniform(-extent, extent, size=(n, 3))
    lo, hi = np.log(scale_range[0]), np.log(scale_range[1])
    scales = np.exp(rng.uniform(lo, hi, size=(n, 3)))
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    colors = rng.random((n, 3))
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    opac = rng.uniform(0.05, 1.0, size=n)
    vis = (rng.random(n) < 0.5).astype(np.uint8)
    f32 = np.float32
    return Snapshot(means.astype(f32), scales.astype(f32), quats.astype(f32), colors.astype(f32), opac.astype(f32),
                    normals.astype(f32), vis, version=version)


def framing_camera(size: int, azimuth: float = 20.0, elevation: float = 5.0, fov_y_deg: float = 30.0) -> Camera:
    """A camera looking at the body's centre, distance chosen so 1.7 m fill ~85% of the height."""
    dist = 0.5 * 1.7 / 0.85 / math.tan(math.radians(fov_y_deg) / 2)
    return Camera.orbit(azimuth, elevation, dist, target=(0.0, 0.0, 0.84), width=size, height=size,
                        fov_y_deg=fov_y_deg)


# ----------------------------------------------------------------------------- benchmark
def run(counts, sizes, modes, frames: int, out=sys.stdout) -> list[dict]:
    from renderer.gl_context import context_info, create_offscreen_context
    from renderer.render_modes import RenderMode
    from renderer.splat_renderer import SplatRenderer

    ctx = create_offscreen_context()
    info = context_info(ctx)
    load0 = os.getloadavg()
    print(f"# GL: {info['renderer']} | {info['version']}", file=out)
    print(f"# CPU cores: {os.cpu_count()}, load average before: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}",
          file=out)
    rows = []
    renderer = SplatRenderer(ctx)
    header = f"{'splats':>7} {'res':>5} {'mode':>10} | {'sort':>6} {'upload':>6} {'draw':>7} {'read':>6} | " \
             f"{'fps':>6} {'fps+rb':>6}"
    try:
        for n in counts:
            snap = body_like_snapshot(n, seed=1)
            t0 = time.perf_counter()
            renderer.set_snapshot(snap)
            up = (time.perf_counter() - t0) * 1e3
            print(f"\n# {n} splats: one-time data upload (sanitize + pack + texture) {up:.1f} ms", file=out)
            print(header, file=out)
            print("-" * len(header), file=out)
            for size in sizes:
                for mode in modes:
                    mode = RenderMode.parse(mode)
                    renderer.render(framing_camera(size, azimuth=19.0), mode=mode)  # warm-up
                    acc = {"sort": [], "upload": [], "draw": [], "read": []}
                    for f in range(frames):
                        cam = framing_camera(size, azimuth=20.0 + f)
                        renderer.render(cam, mode=mode, background=(1.0, 1.0, 1.0))
                        st = renderer.stats
                        acc["sort"].append(st.sort_ms)
                        acc["upload"].append(st.upload_ms)
                        acc["draw"].append(st.draw_ms)
                        acc["read"].append(st.readback_ms)
                    m = {k: float(np.mean(v)) for k, v in acc.items()}
                    frame = m["sort"] + m["upload"] + m["draw"]
                    row = dict(splats=n, res=size, mode=mode.value, **m, fps=1000.0 / frame,
                               fps_rb=1000.0 / (frame + m["read"]), drawn=renderer.stats.n_drawn)
                    rows.append(row)
                    print(f"{n:>7} {size:>5} {mode.value:>10} | {m['sort']:6.2f} {m['upload']:6.2f} "
                          f"{m['draw']:7.1f} {m['read']:6.1f} | {row['fps']:6.1f} {row['fps_rb']:6.1f}",
                          file=out, flush=True)
    finally:
        renderer.release()
        ctx.release()
    load1 = os.getloadavg()
    print(f"\n# load average after: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}", file=out)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 frames per case, 16k and 65k splats only")
    ap.add_argument("--counts", type=int, nargs="*", default=None, help="splat counts (default 16384 65536 262144)")
    ap.add_argument("--sizes", type=int, nargs="*", default=None, help="square image sizes (default 512 1024)")
    ap.add_argument("--modes", nargs="*", default=None, help="render modes (default all)")
    ap.add_argument("--frames", type=int, default=None, help="timed frames per case (default 5, quick 2)")
    args = ap.parse_args(argv)
    counts = args.counts or ([16384, 65536] if args.quick else [16384, 65536, 262144])
    sizes = args.sizes or [512, 1024]
    modes = args.modes or ["rgb", "normal", "depth", "alpha", "visibility"]
    frames = args.frames or (2 if args.quick else 5)
    t0 = time.perf_counter()
    run(counts, sizes, modes, frames)
    print(f"# total benchmark time {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
