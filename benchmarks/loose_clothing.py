"""The loose-clothing benchmark: Stage I on the synthetic scenes with garments that have geometry
(clothing=skirt|coat|dress|wide_trousers) and, for reference, the tight scene (clothing=garment);
seen / unseen PSNR, rendered-alpha IoU against the masks (alpha > 0.5) and the hole fraction (the
share of pixels at least 2 px inside the mask whose alpha < 0.9), at the scene's resolution and at
2x (``eval --scale 2``), and a picture per run: ground truth, render and alpha from the front,
the left side, the back and the right side.

    OMP_NUM_THREADS=1 python benchmarks/loose_clothing.py --runs runs/loose [--train --minutes 5]
        [--kinds skirt coat dress wide_trousers garment] [--seed 0]

A run of kind K is RUNS/s1_K (made with ``--train`` when missing:
``wonderhuman-studio train --scene synthetic:seed=S,clothing=K --out RUNS/s1_K --stage 1
--minutes M --threads 1 --seed S --set threads=1``). Writes RUNS/loose_clothing.json, prints a
markdown table, and RUNS/views_K.png. ``--with-layer`` adds the trained avatar PLUS the untrained
garment-layer prototype (reconstruct/avatar/garment_layer.py: hint read from the training masks,
colours projected from the training frames) evaluated the same way (RUNS/views_K_layer.png).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

KINDS = ("skirt", "coat", "dress", "wide_trousers", "garment")
METRICS = ("psnr", "alpha_iou", "hole_fraction")


def train(run: Path, kind: str, seed: int, minutes: float) -> None:
    cmd = [sys.executable, "-m", "app.cli", "train", "--scene", f"synthetic:seed={seed},clothing={kind}",
           "--out", str(run), "--stage", "1", "--minutes", str(minutes), "--threads", "1", "--seed", str(seed),
           "--set", "threads=1"]
    print(" ".join(cmd), file=sys.stderr)
    subprocess.run(cmd, check=True, env={**os.environ, "OMP_NUM_THREADS": "1"}, cwd=ROOT)


def views_picture(trainer, out: Path, azimuths=(0.0, 90.0, 180.0, 270.0)) -> None:
    """Ground truth / render / alpha (rows) for the middle evaluation frame at ``azimuths`` (columns)."""
    import imageio.v3 as iio
    import torch

    from reconstruct.train.render import render_avatar

    scene = trainer.scene
    frames = sorted({v.frame_index for v in scene.eval_views})
    mid = frames[len(frames) // 2]
    cols = []
    with torch.no_grad():
        posed = trainer.state.posed(mid)
        for az in azimuths:
            v = min((v for v in scene.eval_views if v.frame_index == mid),
                    key=lambda v: abs((v.azimuth_deg - az + 180) % 360 - 180))
            r = render_avatar(posed, v.camera, trainer.background, normals=False)
            rgb = r.rgb.clamp(0, 1).cpu().numpy()
            alpha = np.repeat(r.alpha.cpu().numpy()[..., None], 3, -1)
            cols.append(np.concatenate([v.image, rgb, alpha], 0))
    iio.imwrite(out, (np.concatenate(cols, 1) * 255 + 0.5).astype(np.uint8))


def paint_layer(layer, body, frames, step: int = 5):
    """Colours for the garment layer's Gaussians, untrained: the mean image colour at a Gaussian's
    projection over the training frames where it faces the camera inside the mask; Gaussians never
    seen (the back) take the median seen colour of their ring (else of all)."""
    import torch

    n = layer.num_gaussians
    acc, cnt = np.zeros((n, 3)), np.zeros(n)
    for f in frames[::step]:
        means, normals = (t.numpy() for t in layer.posed(body, f.pose))
        centre = -f.camera.R.T @ f.camera.t
        view = means - centre
        facing = (normals * view).sum(1) < -0.3 * np.linalg.norm(view, axis=1)
        uv, _ = f.camera.project(means)
        u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        H, W = f.mask.shape
        ok = facing & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        ok[ok] &= f.mask[v[ok], u[ok]] > 0.5
        acc[ok] += f.image[v[ok], u[ok]]
        cnt[ok] += 1
    seen = cnt > 0
    col = np.zeros((n, 3))
    col[seen] = acc[seen] / cnt[seen, None]
    R, C = layer.grid_shape
    rows = np.arange(n) // C
    fallback = np.median(col[seen], axis=0) if seen.any() else np.full(3, 0.5)
    for r in range(R):
        on = rows == r
        col[on & ~seen] = np.median(col[on & seen], axis=0) if (on & seen).any() else fallback
    return torch.as_tensor(col, dtype=torch.float32)


def evaluate_with_layer(trainer, picture: Path | None) -> dict:
    """The trained avatar plus the UNTRAINED garment-layer prototype (reconstruct/avatar/garment_layer.py,
    hint and colours from the training frames): what the extra Gaussians buy in coverage."""
    import torch

    from reconstruct.avatar.garment_layer import build_garment_layer, volume_hint_from_masks
    from reconstruct.avatar.model import PosedGaussians
    from reconstruct.metrics import psnr
    from reconstruct.train.evaluate import alpha_iou, hole_fraction, upsample
    from reconstruct.train.render import render_avatar

    scene = trainer.scene
    body = scene.body_model()
    hint = volume_hint_from_masks(body, scene.frames)
    out = {"layer_hint": None if hint is None else {k: round(v, 4) for k, v in hint.__dict__.items()}}
    if hint is None:
        return out
    layer = build_garment_layer(body, hint)
    colors = paint_layer(layer, body, scene.frames)
    out["layer_gaussians"] = layer.num_gaussians
    bg = trainer.background
    rows, pics = [], {}
    with torch.no_grad():
        for scale in (1, 2):
            for v in scene.eval_views:
                a = trainer.state.posed(v.frame_index)
                g = layer.gaussians(body, scene.frames[v.frame_index].pose, colors)
                both = PosedGaussians(*(torch.cat([getattr(a, k), getattr(g, k).to(getattr(a, k))])
                                        for k in ("means", "normals", "colors", "scales", "quats", "opacities")))
                cam = v.camera if scale == 1 else v.camera.scaled(v.camera.width * scale, v.camera.height * scale)
                r = render_avatar(both, cam, bg, normals=False)
                mask_f = upsample(v.mask, scale, bg.device)
                gt = upsample(v.image, scale, bg.device) + (1 - mask_f[..., None]) * bg
                m = mask_f > 0.5
                rows.append({"scale": scale, "seen": v.seen, "psnr": float(psnr(r.rgb.clamp(0, 1), gt)),
                             "alpha_iou": alpha_iou(r.alpha, m), "hole_fraction": hole_fraction(r.alpha, m)})
                if scale == 1:
                    pics[(v.frame_index, v.azimuth_deg)] = (r.rgb.clamp(0, 1).numpy(), r.alpha.numpy())
    for scale in (1, 2):
        for g, pick in (("seen", True), ("unseen", False)):
            for m in METRICS:
                vals = [r[m] for r in rows if r["scale"] == scale and r["seen"] == pick and r[m] is not None]
                out[f"layer_{g}_{m}@{scale}x"] = float(np.mean(vals)) if vals else None
    if picture is not None:
        import imageio.v3 as iio

        frames = sorted({v.frame_index for v in scene.eval_views})
        mid = frames[len(frames) // 2]
        cols = []
        for az in (0.0, 90.0, 180.0, 270.0):
            v = min((v for v in scene.eval_views if v.frame_index == mid),
                    key=lambda v: abs((v.azimuth_deg - az + 180) % 360 - 180))
            rgb, alpha = pics[(mid, v.azimuth_deg)]
            cols.append(np.concatenate([v.image, rgb, np.repeat(alpha[..., None], 3, -1)], 0))
        iio.imwrite(picture, (np.concatenate(cols, 1) * 255 + 0.5).astype(np.uint8))
    return out


def evaluate(run: Path, picture: Path | None, layer_picture: Path | None = None, with_layer: bool = False,
             known: dict | None = None) -> dict:
    """Metrics of ``run`` (``known``: its earlier results at the same step, reused)."""
    from reconstruct.run_folder import RunFolder

    rf = RunFolder(run)
    rf.check("evaluate")
    trainer = rf.resume()
    out = {"run": str(run), "step": trainer.step_count}
    if known and known.get("step") == trainer.step_count and "seen_psnr@2x" in known:
        out = dict(known)
        picture = None
    else:
        out.update(_baseline(trainer))
    if picture is not None:
        views_picture(trainer, picture)
    if with_layer:
        out.update(evaluate_with_layer(trainer, layer_picture))
    return out


def _baseline(trainer) -> dict:
    import torch

    from reconstruct.train.evaluate import evaluate_views

    out = {}
    with torch.no_grad():
        for scale in (1, 2):
            _, summary = evaluate_views(trainer.state, trainer.scene, trainer.background, scale=scale)
            for g in ("seen", "unseen"):
                for m in METRICS:
                    out[f"{g}_{m}@{scale}x"] = summary.get(f"{g}_{m}")
    out["gaussians"] = int(trainer.state.posed(0).means.shape[0])
    return out


def table(results: dict) -> str:
    head = ("| clothing | steps | seen PSNR | unseen PSNR | seen IoU | unseen IoU | seen holes | unseen holes "
            "| seen holes 2x | unseen holes 2x |")
    lines = [head, "|" + "---|" * 10]
    pct = lambda x: "-" if x is None else f"{100 * x:.2f}%"
    num = lambda x, f: "-" if x is None else format(x, f)
    for kind, r in results.items():
        lines.append(f"| {kind} | {r['step']} | {num(r['seen_psnr@1x'], '.2f')} | {num(r['unseen_psnr@1x'], '.2f')} "
                     f"| {num(r['seen_alpha_iou@1x'], '.4f')} | {num(r['unseen_alpha_iou@1x'], '.4f')} "
                     f"| {pct(r['seen_hole_fraction@1x'])} | {pct(r['unseen_hole_fraction@1x'])} "
                     f"| {pct(r['seen_hole_fraction@2x'])} | {pct(r['unseen_hole_fraction@2x'])} |")
    return "\n".join(lines)


def layer_table(results: dict) -> str:
    lines = ["| clothing | layer Gaussians | seen PSNR | unseen PSNR | seen IoU | unseen IoU | seen holes 2x "
             "| unseen holes 2x |", "|" + "---|" * 8]
    pct = lambda x: "-" if x is None else f"{100 * x:.2f}%"
    num = lambda x, f: "-" if x is None else format(x, f)
    for kind, r in results.items():
        if "layer_seen_psnr@1x" not in r:
            lines.append(f"| {kind} | no hint (no layer) | | | | | | |")
            continue
        lines.append(f"| {kind} | {r['layer_gaussians']} | {num(r['layer_seen_psnr@1x'], '.2f')} "
                     f"| {num(r['layer_unseen_psnr@1x'], '.2f')} | {num(r['layer_seen_alpha_iou@1x'], '.4f')} "
                     f"| {num(r['layer_unseen_alpha_iou@1x'], '.4f')} | {pct(r['layer_seen_hole_fraction@2x'])} "
                     f"| {pct(r['layer_unseen_hole_fraction@2x'])} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=Path, default=ROOT / "runs" / "loose")
    p.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--train", action="store_true", help="train the runs that are missing")
    p.add_argument("--minutes", type=float, default=5.0)
    p.add_argument("--no-pictures", action="store_true")
    p.add_argument("--with-layer", action="store_true",
                   help="also evaluate the avatar plus the untrained garment-layer prototype")
    a = p.parse_args(argv)
    out = a.runs / "loose_clothing.json"
    previous = json.loads(out.read_text()) if out.is_file() else {}
    results = {}
    for kind in a.kinds:
        run = a.runs / f"s1_{kind}"
        if not (run / "checkpoint.pt").is_file():
            if not a.train:
                print(f"{kind}: no run at {run} (use --train)", file=sys.stderr)
                continue
            train(run, kind, a.seed, a.minutes)
        results[kind] = evaluate(run, None if a.no_pictures else a.runs / f"views_{kind}.png",
                                 None if a.no_pictures else a.runs / f"views_{kind}_layer.png", a.with_layer,
                                 previous.get(kind))
        print(kind, json.dumps(results[kind]), file=sys.stderr)
        out.write_text(json.dumps({**previous, **results}, indent=1))
    out.write_text(json.dumps({**previous, **results}, indent=1))
    print(table(results))
    if a.with_layer:
        print()
        print(layer_table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
