"""Before / after pictures of Stage I runs on a synthetic scene (docs/stage1_*.png).

    python benchmarks/stage1_pictures.py BEFORE_RUN AFTER_RUN [--out docs] [--labels before,after]

writes
* ``stage1_closeup.png``: 1024 x 1024 close-ups of the torso from the front (the seen view at
  azimuth 0) and the back (azimuth 180), ground truth (the scene's 512^2 view upsampled) | before |
  after; the after close-ups alone as ``stage1_closeup_front.png`` / ``stage1_closeup_back.png``;
* ``stage1_studio_before_after.png``: the whole body at the studio's window size (1280 x 800, a
  three-quarter view from azimuth 30, the studio's dark background), before | after.
Rendered with the training rasterizer (one thread is enough).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLOSE = 1024
ZOOM = 4  # close-ups: the 512^2 view at 4x, a 1024^2 window on the torso


def _load(run: Path):
    from reconstruct.run_folder import RunFolder

    return RunFolder(run).resume()


def _torso_box(posed, camera, size: int) -> tuple[int, int, int, int]:
    """A size x size pixel box centred on the projected chest (Gaussians between 62% and 80% of the
    body's height)."""
    m = posed.means.detach().numpy().astype(np.float64)
    z = m[:, 2]
    lo, hi = np.quantile(z, [0.0, 1.0])
    sel = (z > lo + 0.62 * (hi - lo)) & (z < lo + 0.80 * (hi - lo))
    c = np.median(m[sel], axis=0)
    xc = camera.R @ c + camera.t
    u = camera.K[0, 0] * xc[0] / xc[2] + camera.K[0, 2]
    v = camera.K[1, 1] * xc[1] / xc[2] + camera.K[1, 2]
    x0 = int(np.clip(round(u - size / 2), 0, camera.width - size))
    y0 = int(np.clip(round(v - size / 2), 0, camera.height - size))
    return x0, y0, x0 + size, y0 + size


def _render(trainer, posed, camera, background) -> np.ndarray:
    import torch

    from reconstruct.train.render import render_avatar

    with torch.no_grad():
        r = render_avatar(posed, camera, torch.tensor(background, dtype=torch.float32), normals=False)
    return (r.rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8)


def _label(img: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    d = ImageDraw.Draw(im)
    d.rectangle([0, 0, 12 + 8 * len(text), 22], fill=(0, 0, 0))
    d.text((6, 5), text, fill=(255, 255, 255))
    return np.asarray(im)


def main() -> None:
    import torch
    from PIL import Image

    from reconstruct.train.render import crop_camera

    torch.set_num_threads(1)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--out", type=Path, default=ROOT / "docs")
    ap.add_argument("--labels", default="before,after", help="two labels, comma-separated (no commas inside)")
    args = ap.parse_args()
    labels = args.labels.split(",")
    trainers = [_load(args.before), _load(args.after)]
    scene = trainers[1].scene
    views = {round(v.azimuth_deg) % 360: v for v in scene.eval_views}
    rows, singles = [], {}
    for name, az in (("front", 0), ("back", 180)):
        v = views[az]
        big = v.camera.scaled(v.camera.width * ZOOM, v.camera.height * ZOOM)
        posed = [t.state.posed(v.frame_index) for t in trainers]
        box = _torso_box(posed[1], big, CLOSE)
        cam = crop_camera(big, box)
        x0, y0, x1, y1 = (b // ZOOM for b in box)
        gt = np.asarray(v.image[y0:y1, x0:x1] * v.mask[y0:y1, x0:x1, None])
        gt = np.asarray(Image.fromarray((gt.clip(0, 1) * 255).round().astype(np.uint8)).resize((CLOSE, CLOSE),
                                                                                              Image.BILINEAR))
        renders = [_render(t, p, cam, (0.0, 0.0, 0.0)) for t, p in zip(trainers, posed)]
        singles[name] = renders[1]
        rows.append(np.concatenate([_label(gt, f"ground truth ({name}, 512^2 view upsampled)")]
                                   + [_label(r, f"{lab} ({name})") for r, lab in zip(renders, labels)], 1))
    args.out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, 0)).resize((3 * CLOSE // 2, CLOSE), Image.LANCZOS).save(
        args.out / "stage1_closeup.png")
    for name, img in singles.items():
        Image.fromarray(img).save(args.out / f"stage1_closeup_{name}.png")
    # the studio's window: whole body, three-quarter view
    from reconstruct.camera import Camera

    v = views[30] if 30 in views else views[0]
    posed = [t.state.posed(v.frame_index) for t in trainers]
    m = posed[1].means.detach().numpy().astype(np.float64)
    centre = 0.5 * (m.min(0) + m.max(0))
    eye = v.camera.center - centre
    eye = centre + eye / np.linalg.norm(eye) * 2.5
    cam = Camera.look_at(eye, centre, width=1280, height=800, fov_y_deg=40.0)
    bg = (0.12, 0.12, 0.14)
    shots = [_label(_render(t, p, cam, bg), lab) for t, p, lab in zip(trainers, posed, labels)]
    Image.fromarray(np.concatenate(shots, 1)).save(args.out / "stage1_studio_before_after.png")
    print(f"wrote {args.out}/stage1_closeup.png, stage1_closeup_front.png, stage1_closeup_back.png, "
          f"stage1_studio_before_after.png")


if __name__ == "__main__":
    main()
