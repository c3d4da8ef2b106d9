"""Where a run's rendered outline leaves the ground truth's: per evaluation view, the pixels the
avatar covers outside the mask (excess) and the mask's pixels it leaves open (deficit), each as a
share of the mask's area, the excess split by whose Gaussians draw it (the garment layer's, the
body's, or only the two together) and by where it lies in its image row (left of the mask's run,
right of it, or in a gap between the mask's runs, as between two legs).

    OMP_NUM_THREADS=1 python benchmarks/outline_excess.py RUN [RUN ...] [--scale 1] [--sheet OUT.png]

A pixel is covered when the rendered alpha exceeds 0.5 (``eval``'s alpha IoU threshold). The
excess's width is also given in millimetres at the person: per image row with excess at one end,
its pixel count times the depth of the rendered surface over the focal length, the median over the
rows. In a side view (azimuth near 90 or 270 degrees) the two ends of a row are the front and the
back of the body, so this is the depth the avatar's cloth stands past the garment's. ``--sheet``
writes, for every view, the ground truth with the excess painted (red: the layer's, blue: the
body's, magenta: the two together) and the deficit in green.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruct.atomic import atomic_output  # noqa: E402
from reconstruct.train.evaluate import IOU_ALPHA, rendered_views  # noqa: E402
from reconstruct.train.render import render_avatar  # noqa: E402


def row_sides(cover: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(left, right, between) boolean maps splitting the covered pixels outside ``mask`` (both
    (H,W) bool) by where they lie in their row: left of the row's first mask pixel, right of its
    last, or in between (a gap in the mask's row). Rows without mask pixels count as neither."""
    W = mask.shape[1]
    cols = np.arange(W)[None, :]
    any_row = mask.any(1)
    first = np.where(any_row, mask.argmax(1), W)[:, None]
    last = np.where(any_row, W - 1 - mask[:, ::-1].argmax(1), -1)[:, None]
    out = cover & ~mask & any_row[:, None]
    return out & (cols < first), out & (cols > last), out & (cols > first) & (cols < last)


def row_widths_mm(side: np.ndarray, depth: np.ndarray, focal: float) -> np.ndarray:
    """Per row with any pixel of ``side`` ((H,W) bool): its pixel count times the median depth
    (metres) of those pixels over ``focal`` (pixels), in millimetres."""
    rows = np.nonzero(side.any(1))[0]
    out = []
    for r in rows:
        d = depth[r][side[r]]
        d = d[np.isfinite(d) & (d > 0)]
        if len(d):
            out.append(1000.0 * side[r].sum() * float(np.median(d)) / focal)
    return np.asarray(out)


def excess_owners(cover: np.ndarray, mask: np.ndarray, layer: np.ndarray | None,
                  body: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(excess, by_layer, by_body): the covered pixels outside ``mask``, those the layer alone
    covers (none without a layer), and those the body alone covers and the layer does not. The
    rest of the excess is covered only by the two together."""
    excess = cover & ~mask
    by_layer = excess & layer if layer is not None else np.zeros_like(excess)
    return excess, by_layer, excess & body & ~by_layer


def view_excess(cover: np.ndarray, mask: np.ndarray, layer: np.ndarray | None, body: np.ndarray,
                depth: np.ndarray, focal: float) -> dict:
    """The numbers of the module docstring for one view: ``cover``, ``layer``, ``body`` are the
    (H,W) bool coverage of the whole avatar, the layer alone (None without one) and the body alone."""
    area = max(int(mask.sum()), 1)
    excess, by_layer, by_body = excess_owners(cover, mask, layer, body)
    left, right, between = row_sides(cover, mask)
    wl, wr = row_widths_mm(left, depth, focal), row_widths_mm(right, depth, focal)
    return {"excess": excess.sum() / area, "deficit": (mask & ~cover).sum() / area,
            "layer": by_layer.sum() / area, "body": by_body.sum() / area,
            "together": (excess & ~by_layer & ~by_body).sum() / area,
            "left": left.sum() / area, "right": right.sum() / area, "between": between.sum() / area,
            "left_mm": float(np.median(wl)) if len(wl) else 0.0,
            "right_mm": float(np.median(wr)) if len(wr) else 0.0}


def _only(posed, keep: torch.Tensor):
    """``posed`` with the opacity of every Gaussian outside ``keep`` set to 0."""
    return dataclasses.replace(posed, opacities=posed.opacities * keep.to(posed.opacities.dtype))


@torch.no_grad()
def run_excess(run: Path, scale: int = 1) -> tuple[list[dict], list[np.ndarray]]:
    """Per evaluation view of ``run``: its azimuth, seen flag and ``view_excess``; and a picture of
    each (the module docstring's sheet)."""
    from reconstruct.run_folder import RunFolder

    trainer = RunFolder(run).resume()
    state, scene, bg = trainer.state, trainer.scene, trainer.background
    model = state.model
    nb, n = model.num_body, model.num_gaussians
    is_layer = torch.zeros(n, dtype=torch.bool, device=bg.device)
    is_layer[nb:] = True
    rows, pictures = [], []
    posed_at = {}
    for v, r, gt, mask_t in rendered_views(state, scene, bg, scale=scale):
        if v.frame_index not in posed_at:
            posed_at[v.frame_index] = state.posed(v.frame_index)
        posed = posed_at[v.frame_index]
        cam = v.camera if scale == 1 else v.camera.scaled(v.camera.width * scale, v.camera.height * scale)
        extra = posed.means.shape[0] - n  # Stage II's pose-dependent Gaussians count as the body's
        keep_layer = torch.cat([is_layer, torch.zeros(max(extra, 0), dtype=torch.bool, device=bg.device)])
        cover = (r.alpha > IOU_ALPHA).cpu().numpy()
        body = (render_avatar(_only(posed, ~keep_layer), cam, bg, normals=False).alpha > IOU_ALPHA).cpu().numpy()
        layer = None
        if model.num_layer:
            layer = (render_avatar(_only(posed, keep_layer), cam, bg, normals=False).alpha > IOU_ALPHA).cpu().numpy()
        mask = mask_t.cpu().numpy()
        depth = r.depth.cpu().numpy() if r.depth is not None else np.ones(mask.shape)
        depth = depth.reshape(mask.shape)
        e = view_excess(cover, mask, layer, body, depth, float(cam.K[0, 0]))
        rows.append({"azimuth": float(v.azimuth_deg), "seen": bool(v.seen), "frame": int(v.frame_index), **e})
        pic = gt.cpu().numpy().copy() * 0.6 + 0.4
        ex, lay, bod = excess_owners(cover, mask, layer, body)
        pic[lay] = (0.9, 0.1, 0.1)
        pic[bod] = (0.1, 0.2, 0.9)
        pic[ex & ~lay & ~bod] = (0.8, 0.1, 0.8)
        pic[mask & ~cover] = (0.1, 0.7, 0.1)
        pictures.append(pic)
    return rows, pictures


def per_azimuth(rows: list[dict]) -> list[dict]:
    """``rows`` averaged over the frames of each azimuth."""
    out = []
    for az in sorted({r["azimuth"] for r in rows}):
        group = [r for r in rows if r["azimuth"] == az]
        avg = {k: float(np.mean([g[k] for g in group])) for k in group[0] if k not in ("seen", "frame")}
        avg["seen"] = group[0]["seen"]
        out.append(avg)
    return out


def table(name: str, rows: list[dict]) -> str:
    lines = [f"{name}: share of the mask's area (%), widths at the person (mm, median over rows)",
             "| azimuth | seen | excess | by layer / body / together | left / right / between | left / right mm | deficit |",
             "|---|---|---|---|---|---|---|"]
    for a in per_azimuth(rows):
        lines.append(f"| {a['azimuth']:.0f} | {'yes' if a['seen'] else 'no'} | {100 * a['excess']:.2f} | "
                     f"{100 * a['layer']:.2f} / {100 * a['body']:.2f} / {100 * a['together']:.2f} | "
                     f"{100 * a['left']:.2f} / {100 * a['right']:.2f} / {100 * a['between']:.2f} | "
                     f"{a['left_mm']:.1f} / {a['right_mm']:.1f} | {100 * a['deficit']:.2f} |")
    return "\n".join(lines)


def sheet(pictures: list[np.ndarray], columns: int) -> np.ndarray:
    h = max(p.shape[0] for p in pictures)
    w = max(p.shape[1] for p in pictures)
    rows = -(-len(pictures) // columns)
    out = np.ones((rows * h, columns * w, 3))
    for i, p in enumerate(pictures):
        y, x = divmod(i, columns)
        out[y * h:y * h + p.shape[0], x * w:x * w + p.shape[1]] = p
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--scale", type=int, default=1, help="render at this multiple of the views' resolution")
    p.add_argument("--sheet", type=Path, help="write the pictures of the last run here (PNG)")
    args = p.parse_args(argv)
    if args.scale < 1:
        p.error(f"--scale must be a positive integer, found {args.scale}")
    torch.set_num_threads(1)
    pictures = []
    for run in args.runs:
        rows, pictures = run_excess(run, args.scale)
        print(table(run.name, rows))
    if args.sheet is not None and pictures:
        from PIL import Image

        img = sheet(pictures, columns=12 if len(pictures) % 12 == 0 else 6)
        with atomic_output(args.sheet) as tmp:
            Image.fromarray((np.clip(img, 0, 1) * 255).astype(np.uint8)).save(tmp)
        print(f"wrote {args.sheet}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
