"""How much of a run's error its colours hold: the Gaussians' colours fitted to the evaluation
views' own ground truth, everything else kept, then scored again. The gain is an upper bound on
what any better appearance (the unseen fill, Stage II's prior, a finer colour model per Gaussian)
could give this geometry; what is left is geometry and resolution (the silhouette, the Gaussians'
size and density).

    OMP_NUM_THREADS=1 python benchmarks/appearance_bound.py RUN [RUN ...] [--which all|layer]
        [--epochs 10] [--lr 0.003] [--scale 1]

Only the per-Gaussian colour residual (``AvatarConfig.color_residual``) moves: of every Gaussian
(``--which all``) or of the garment layer's alone (``--which layer``), by Adam at ``--lr`` over
``--epochs`` passes of every evaluation view (seen and unseen alike, one step per view), at
``--scale`` x the views' resolution against their ground truth upsampled as ``eval --scale`` does.
The run folder is read, never written. Prints a markdown table: PSNR seen / unseen before and
after (means over the views, as ``eval``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruct.train.evaluate import evaluate_views, upsample  # noqa: E402
from reconstruct.train.render import render_avatar  # noqa: E402


def fit_colours(state, views, background: torch.Tensor, rows: torch.Tensor, *, epochs: int = 10,
                lr: float = 0.003, scale: int = 1) -> list[float]:
    """Adam on ``state.model``'s colour residual at the Gaussians ``rows`` ((N,) bool), one step per
    view of ``views`` per epoch, on the squared error against each view's ground truth (over
    ``background``, at ``scale``); the other parameters are left as they are. Returns each epoch's
    mean loss (before its steps' updates took effect on later views)."""
    model = state.model
    residual = getattr(model.decoder, "color_residual", None)
    if residual is None:
        raise ValueError("appearance bound: the avatar has no per-Gaussian colour residual "
                         "(AvatarConfig.color_residual is off)")
    rows = torch.as_tensor(rows, dtype=torch.bool, device=residual.device)
    if rows.shape != (residual.shape[0],):
        raise ValueError(f"appearance bound: rows must be ({residual.shape[0]},) bool, found {tuple(rows.shape)}")
    keep = rows[:, None].to(residual.dtype)
    was = {p: p.requires_grad for p in model.parameters()}
    for p in model.parameters():  # the rasteriser keeps a graph only when something needs one
        p.requires_grad_(p is residual)
    optimizer = torch.optim.Adam([residual], lr=lr)
    losses = []
    try:
        for _ in range(epochs):
            total = 0.0
            for v in views:
                cam = v.camera if scale == 1 else v.camera.scaled(v.camera.width * scale, v.camera.height * scale)
                out = render_avatar(state.posed(v.frame_index), cam, background, normals=False)
                mask = upsample(v.mask, scale, background.device)
                gt = upsample(v.image, scale, background.device) + (1 - mask[..., None]) * background
                loss = (out.rgb - gt).square().mean()
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                residual.grad *= keep
                optimizer.step()
                total += float(loss.detach())
            losses.append(total / max(len(views), 1))
    finally:
        for p, flag in was.items():
            p.requires_grad_(flag)
    return losses


def run_bound(run: Path, which: str = "all", epochs: int = 10, lr: float = 0.003, scale: int = 1) -> dict:
    from reconstruct.run_folder import RunFolder

    trainer = RunFolder(run).resume()
    state, scene = trainer.state, trainer.scene
    model = state.model
    rows = torch.ones(model.num_gaussians, dtype=torch.bool)
    if which == "layer":
        if model.num_layer == 0:
            raise ValueError(f"{run}: --which layer needs a run with a garment layer")
        rows[: model.num_body] = False
    elif which != "all":
        raise ValueError(f"appearance bound: --which must be 'all' or 'layer', found {which!r}")
    _, before = evaluate_views(state, scene, trainer.background, scale=scale)
    losses = fit_colours(state, scene.eval_views, trainer.background, rows, epochs=epochs, lr=lr, scale=scale)
    _, after = evaluate_views(state, scene, trainer.background, scale=scale)
    return {"before": before, "after": after, "losses": losses, "fitted": int(rows.sum())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--which", default="all", choices=["all", "layer"], help="whose colours are fitted")
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--lr", type=float, default=0.003, help="Adam's rate on the colour residual's parameter")
    p.add_argument("--scale", type=int, default=1, help="render at this multiple of the views' resolution")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    print(f"colours fitted: {args.which}, {args.epochs} epochs, lr {args.lr}, ×{args.scale}")
    print("| run | Gaussians fitted | PSNR seen / unseen | fitted: seen / unseen | gain seen / unseen |")
    print("|---|---|---|---|---|")
    for run in args.runs:
        r = run_bound(run, args.which, args.epochs, args.lr, args.scale)
        b, a = r["before"], r["after"]
        print(f"| {run.name} | {r['fitted']:,} | {b['seen_psnr']:.2f} / {b['unseen_psnr']:.2f} | "
              f"{a['seen_psnr']:.2f} / {a['unseen_psnr']:.2f} | {a['seen_psnr'] - b['seen_psnr']:+.2f} / "
              f"{a['unseen_psnr'] - b['unseen_psnr']:+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
