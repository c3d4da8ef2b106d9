"""How well a trained avatar covers and fits its own training views: for runs on real footage
(``prepare``d photos and videos), which have no evaluation views from other cameras.

Per run and training frame (all frames, or ``--frames``), rendered from the frame's camera on
black: PSNR inside the mask (pixels with mask > 0.5, the image premultiplied by the mask as
training sees it), the hole share (pixels at least 2 px inside the mask, as ``eval``'s holes, with
rendered alpha < 0.9), the alpha IoU (alpha > 0.5 against mask > 0.5) and the spill (pixels with
alpha > 0.5 off the mask, as a share of the mask). Prints one row per run (the means over its
frames) and how speckled its unseen side is (``back_specks``: frame 0's pose from 135, 180 and
225 degrees, the share of the inside 0.2 brighter than the median of its 9 x 9 neighbourhood) and
its sides (``side_specks``: from 60, 90, 270 and 300 degrees, 0.2 brighter or darker);
``--strip DIR`` also writes, per run, an 8-view orbit strip of frame 0's pose
(``RUN_orbit.png``, 0° = the frame's camera).

    python benchmarks/photo_fit.py RUN [RUN ...] [--frames 0,3] [--strip DIR] [--size 320]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import binary_erosion

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruct.camera import Camera  # noqa: E402
from reconstruct.run_folder import RunFolder  # noqa: E402
from reconstruct.train.render import render_avatar  # noqa: E402

INSET = 2  # px: holes are counted this far inside the mask (as eval's hole fraction)


def frame_fit(posed, frame) -> dict[str, float]:
    """The fit numbers of one rendered training frame (see the module docstring)."""
    out = render_avatar(posed, frame.camera, torch.zeros(3), normals=False)
    rgb = out.rgb.detach().double().numpy()
    alpha = out.alpha.detach().double().numpy()
    mask = np.asarray(frame.mask, np.float64)
    target = np.asarray(frame.image, np.float64) * mask[..., None]
    on = mask > 0.5
    mse = float(((rgb - target)[on] ** 2).mean())
    inner = binary_erosion(on, iterations=INSET)
    drawn = alpha > 0.5
    return {"psnr_mask": -10 * np.log10(max(mse, 1e-12)),
            "holes": float((alpha[inner] < 0.9).mean()) if inner.any() else float("nan"),
            "iou": float((drawn & on).sum() / max((drawn | on).sum(), 1)),
            "spill": float((drawn & ~on).sum() / max(on.sum(), 1))}


def orbit_renders(trainer, frame_index: int, size: int, azimuths) -> list:
    """Frame ``frame_index``'s pose seen from each azimuth (degrees, 0 = the frame's camera) at the
    camera's distance and height, looking at the Gaussians' centre: the renders on black."""
    posed = trainer.state.posed(frame_index)
    cam = trainer.scene.frames[frame_index].camera
    centre = posed.means.detach().double().numpy().mean(0)
    eye = -cam.R.T @ cam.t
    front = eye - centre
    dist = float(np.linalg.norm(front))
    front[2] = 0
    front /= np.linalg.norm(front)
    out = []
    for az in azimuths:
        a = np.radians(az)
        v = np.array([front[0] * np.cos(a) - front[1] * np.sin(a), front[0] * np.sin(a) + front[1] * np.cos(a), 0.0])
        view = Camera.look_at(centre + dist * v, centre, width=size, height=size, fov_y_deg=40)
        out.append(render_avatar(posed, view, torch.zeros(3), normals=False))
    return out


def orbit_strip(trainer, frame_index: int, size: int) -> np.ndarray:
    """(size, 8*size, 3) uint8: frame ``frame_index``'s pose from 8 azimuths round its centre."""
    tiles = [(np.clip(r.rgb.detach().numpy(), 0, 1) * 255).astype(np.uint8)
             for r in orbit_renders(trainer, frame_index, size, range(0, 360, 45))]
    return np.concatenate(tiles, axis=1)


SPECK_STEP = 0.2  # a speck pixel is this much brighter (mean of RGB) than the median round it
SPECK_WINDOW = 9  # px: the side of the square whose median it is compared with


def speck_share(rgb: np.ndarray, alpha: np.ndarray, *, dark: bool = False) -> float:
    """Share of the inside of a render (alpha > 0.99 over the whole ``SPECK_WINDOW`` square round
    the pixel) whose brightness exceeds the median of that square by ``SPECK_STEP``: isolated light
    dots and streaks on a surface, which a mottled or speckled back shows and a smooth one does
    not. With ``dark``, those below the median by as much are counted too (dark dashes down a
    limb seen from the side). Edges between two flat regions are not counted (the median follows
    the side the pixel is on)."""
    from scipy.ndimage import minimum_filter, median_filter

    lum = np.asarray(rgb, np.float64).mean(-1)
    inside = minimum_filter(np.asarray(alpha, np.float64), size=SPECK_WINDOW) > 0.99
    if not inside.any():
        return float("nan")
    step = lum - median_filter(lum, size=SPECK_WINDOW)
    speck = (np.abs(step) if dark else step) > SPECK_STEP
    return float(speck[inside].mean())


def orbit_specks(trainer, frame_index: int, size: int, azimuths, *, dark: bool = False) -> float:
    """``speck_share`` of frame ``frame_index``'s pose seen from ``azimuths`` (pixels pooled)."""
    rows = [(r.rgb.detach().numpy(), r.alpha.detach().numpy())
            for r in orbit_renders(trainer, frame_index, size, azimuths)]
    rgb = np.concatenate([r for r, _ in rows], axis=1)
    alpha = np.concatenate([a for _, a in rows], axis=1)
    return speck_share(rgb, alpha, dark=dark)


def back_specks(trainer, frame_index: int, size: int) -> float:
    """Light specks from 135, 180 and 225 degrees: how speckled the side no training view showed is."""
    return orbit_specks(trainer, frame_index, size, (135, 180, 225))


def side_specks(trainer, frame_index: int, size: int) -> float:
    """Light and dark specks from 60, 90, 270 and 300 degrees: the sides, which a front view sees
    only at grazing incidence (its silhouette's colours)."""
    return orbit_specks(trainer, frame_index, size, (60, 90, 270, 300), dark=True)


@torch.no_grad()
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--frames", default=None, help="comma-separated training frame indices (default: all)")
    ap.add_argument("--strip", type=Path, default=None, help="folder for the orbit strips")
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    print(f"{'run':<28} {'frames':>6} {'PSNR mask':>9} {'holes %':>8} {'IoU':>7} {'spill %':>8} {'layer':>6} "
          f"{'back specks %':>13} {'side specks %':>13}")
    for run in args.runs:
        t = RunFolder(run).resume()
        frames = (range(len(t.scene.frames)) if args.frames is None
                  else [int(i) for i in args.frames.split(",")])
        rows = [frame_fit(t.state.posed(i), t.scene.frames[i]) for i in frames]
        mean = {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]}
        print(f"{run.name:<28} {len(rows):>6} {mean['psnr_mask']:9.2f} {100 * mean['holes']:8.2f} "
              f"{mean['iou']:7.4f} {100 * mean['spill']:8.2f} {t.state.model.num_layer:>6} "
              f"{100 * back_specks(t, 0, args.size):13.3f} {100 * side_specks(t, 0, args.size):13.3f}")
        if args.strip is not None:
            from PIL import Image
            args.strip.mkdir(parents=True, exist_ok=True)
            Image.fromarray(orbit_strip(t, 0, args.size)).save(args.strip / f"{run.name}_orbit.png")


if __name__ == "__main__":
    main()
