"""Issue 22's measurement: on a run after Stage II, paint the back's region where the front emblem
repeats unseen and redo it (headless ``edit``), run N more Stage II steps, and compare with the same
N steps without the edit: front-leak and PSNR on the back views, before / after pictures.

    python benchmarks/edits_redo.py RUN --steps 40 --out OUT

RUN is left as it is (copied to OUT/control and OUT/edited).

``--inject-mirror-leak``: first make the failure the edit is for -- a back hallucinated by copying
the front -- on a copy of RUN (OUT/leaky): the unseen torso Gaussians take the colour of the seen
Gaussian nearest their mirror image through the torso's coronal plane (``mirror_colors``, the front
emblem lands on the back), written into the per-Gaussian colour residual of the trained model (so
it is the model, not an edit, and training continues from it). Both arms start from that copy.
"""

from __future__ import annotations

import argparse
import gc
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def back_views(scene, spread: float = 60.0):
    return [v for v in scene.eval_views
            if not v.seen and abs(((v.azimuth_deg - 180.0 + 180.0) % 360.0) - 180.0) <= spread]


def measure(trainer, views) -> dict:
    rows, summary = trainer.evaluate(views)
    back = [r for r in rows if abs(((r["azimuth_deg"] - 180.0 + 180.0) % 360.0) - 180.0) < 1]
    leaks = [r["front_leak"] for r in rows if r.get("front_leak") is not None]
    return {"front_leak": summary.get("front_leak"), "back_views_psnr": summary.get("unseen_psnr"),
            "back_180_psnr": float(np.mean([r["psnr"] for r in back])) if back else None,
            "back_180_front_leak": (float(np.mean([r["front_leak"] for r in back if r.get("front_leak") is not None]))
                                    if any(r.get("front_leak") is not None for r in back) else None),
            "views": len(rows), "views_with_leak": len(leaks)}


@torch.no_grad()
def render(trainer, view) -> np.ndarray:
    from reconstruct.train.render import render_avatar

    r = render_avatar(trainer.state.posed(view.frame_index), view.camera, trainer.background, normals=False)
    return r.rgb.clamp(0, 1).cpu().numpy()


def emblem_rect(view, pad: int = 4) -> tuple[int, int, int, int]:
    info = view.front_leak
    names = list(info.names)
    k = next((i for i, n in enumerate(names) if "emblem" in n), 0)
    cov = info.regions[..., k]
    ys, xs = np.nonzero(cov > 0.3)
    if len(xs) == 0:
        raise SystemExit(f"view {view.camera.name}: no emblem region visible")
    H, W = cov.shape
    return (max(0, xs.min() - pad), max(0, ys.min() - pad), min(W, xs.max() + 1 + pad), min(H, ys.max() + 1 + pad))


@torch.no_grad()
def inject_mirror_leak(run) -> None:
    from reconstruct.body.parts import PART_INDEX
    from reconstruct.appearance.propagation import mirror_colors

    t = run.resume_training()
    state, model = t.state, t.state.model
    res = model.decoder.color_residual
    colors = state.canonical(None).colors
    seen = state.trusted_seen.numpy()
    mirrored, matched = mirror_colors(model.base_positions.double().numpy(), model.parts(), seen,
                                      colors.double().numpy())
    pick = torch.as_tensor(matched & ~seen & (model.parts() == PART_INDEX["torso"]))
    lg = lambda c: torch.logit(torch.as_tensor(c, dtype=torch.float32).clamp(1e-4, 1 - 1e-4))  # noqa: E731
    res[pick] += lg(mirrored)[pick] - lg(colors)[pick]
    t.save()
    print(f"injected the mirrored front into {int(pick.sum())} unseen torso Gaussians of {run.path}")


def main() -> int:
    from app.cli import main as cli
    from reconstruct.run_folder import RunFolder

    ap = argparse.ArgumentParser()
    ap.add_argument("run", type=Path)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--grow", type=int, default=2)
    ap.add_argument("--inject-mirror-leak", action="store_true")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    source = args.run
    if args.inject_mirror_leak:
        source = args.out / "leaky"
        if source.exists():
            shutil.rmtree(source)
        shutil.copytree(args.run, source, ignore=shutil.ignore_patterns(".lock", "edits"))
        inject_mirror_leak(RunFolder(source))
    folders = {}
    for name in ("control", "edited"):
        dst = args.out / name
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(source, dst, ignore=shutil.ignore_patterns(".lock", "edits"))
        folders[name] = dst
    t = RunFolder(folders["control"]).resume_training()
    scene = t.scene
    views = back_views(scene)
    back = min((v for v in views if v.front_leak is not None),
               key=lambda v: (abs(v.azimuth_deg - 180.0), v.frame_index))
    results = {"before": measure(t, views)}
    pics = {"ground truth": back.image + (1 - back.mask[..., None]) * t.background.numpy(), "before": render(t, back)}
    stage_step = t.stage_step
    del t
    gc.collect()
    # the edit, headless: the back view's emblem region (visible surface, torso only), unseen, then redo
    x0, y0, x1, y1 = emblem_rect(back)
    sel = f"rect={x0},{y0},{x1},{y1}@eval={back.camera.name}"
    t0 = time.perf_counter()
    assert cli(["edit", str(folders["edited"]), "--select", sel, "--select=&part=torso", "--grow", str(args.grow),
                "--op", "unseen"]) == 0
    assert cli(["edit", str(folders["edited"]), "--select", "edit=1", "--op", "redo"]) == 0
    edit_s = time.perf_counter() - t0
    for name, folder in folders.items():
        tr = RunFolder(folder).resume_training(stage2_overrides={"iters": stage_step + args.steps})
        if name == "control":
            # the edited arm's plan redoes its view selection and propagated colours for the painted
            # map (from the current colours); the control's plan does the same for the unpainted one,
            # so the two differ by the edit alone
            tr.plan.refresh_visibility(tr.state)
        else:
            results["edited, before training"] = measure(tr, views)
            pics["redo (0 steps)"] = render(tr, back)
        t1 = time.perf_counter()
        for _ in range(args.steps):
            tr.step()
        results[f"{name}, after {args.steps} steps"] = {**measure(tr, views),
                                                       "train_s": round(time.perf_counter() - t1, 1)}
        pics[f"{name} +{args.steps}"] = render(tr, back)
        if name == "edited":
            edited = tr.state.edits
        del tr
        gc.collect()
    results["edit"] = {"select": sel, "grow": args.grow, "gaussians": int(edited.entries[0].count),
                       "back_view": back.camera.name, "frame": back.frame_index, "edit_command_s": round(edit_s, 1),
                       "stage2_step_at_start": stage_step}
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    print(json.dumps(results, indent=1))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cov = back.front_leak.regions[..., 0] > 0.3
    gt = pics["ground truth"]
    results["region_rgb_error"] = {k: float(np.abs(v - gt)[cov].mean()) for k, v in pics.items()}
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    print("mean |render - ground truth| over the back view's emblem region:", results["region_rgb_error"])
    cx, cy, h = (x0 + x1) // 2, (y0 + y1) // 2, 70
    zoom = (slice(max(0, cy - h), cy + h), slice(max(0, cx - h), cx + h))
    fig, axes = plt.subplots(1, len(pics), figsize=(2.6 * len(pics), 3.0))
    for ax, (title, img) in zip(axes, pics.items()):
        ax.imshow(np.clip(img[zoom], 0, 1))
        ax.add_patch(matplotlib.patches.Rectangle((x0 - zoom[1].start, y0 - zoom[0].start), x1 - x0, y1 - y0,
                                                  fill=False, ec="yellow", lw=0.8))
        ax.set_title(f"{title}\n|err| {results['region_rgb_error'][title]:.3f}", fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(args.out / "before_after_zoom.png", dpi=110)
    plt.close(fig)
    fig, axes = plt.subplots(1, len(pics), figsize=(3.2 * len(pics), 3.6))
    for ax, (title, img) in zip(axes, pics.items()):
        ax.imshow(np.clip(img, 0, 1))
        ax.set_title(title, fontsize=9)
        ax.add_patch(matplotlib.patches.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="yellow", lw=0.6))
        ax.axis("off")
    fig.suptitle(f"{back.camera.name} (frame {back.frame_index}): back view, emblem region boxed", fontsize=10)
    fig.tight_layout()
    fig.savefig(args.out / "before_after.png", dpi=110)
    print(f"wrote {args.out / 'before_after.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
