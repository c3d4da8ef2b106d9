"""Poke-through of the body through a trained avatar's garment layer: how much of the layer's own
opaque silhouette shows a leg or the torso instead (docs/loose_clothing.md, "The layer kept clear
of the posed body").

For each pose and camera the avatar is rendered twice: whole (first hits), and the layer alone
(the body's opacities set to 0). Poke-through is the share of the pixels where the layer alone is
opaque (alpha > 0.9) whose first hit in the whole render is a torso, thigh or shin Gaussian of the
body. The cameras stand round the pose's centre at 3.2 m, 45° apart (the training frame's camera
at 0°), or, with ``--walk``, at 0/90/180/270° round 8 poses of the walk cycle placed on frame 0's
pose. Each run is measured with its layer kept clear of the body (``--clearance``, default 5 mm)
and without (0), on the same checkpoint:

    python benchmarks/layer_poke.py RUN [RUN ...] [--frame 0] [--walk] [--clearance 0.005]

prints one row per run and clearance: the share per azimuth and the mean.
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

from reconstruct.body.novel_poses import novel_pose_sequence  # noqa: E402
from reconstruct.body.parts import PART_INDEX  # noqa: E402
from reconstruct.camera import Camera  # noqa: E402
from reconstruct.run_folder import RunFolder  # noqa: E402
from reconstruct.train.render import render_avatar  # noqa: E402

UNDER = ("torso", "thigh.L", "thigh.R", "shin.L", "shin.R")


@torch.no_grad()
def poke_through(posed, under: np.ndarray, num_body: int, camera) -> float:
    """Percent of the layer-alone opaque pixels whose first hit is a body Gaussian in ``under``."""
    whole = render_avatar(posed, camera, torch.zeros(3), normals=False, first_hit=True)
    opacity = posed.opacities.clone()
    opacity[:num_body] = 0
    layer = render_avatar(dataclasses.replace(posed, opacities=opacity), camera, torch.zeros(3), normals=False)
    inside = layer.alpha.numpy() > 0.9
    hit = whole.first_hit.numpy()
    body_hit = (hit >= 0) & (hit < num_body)
    poke = inside & body_hit & under[np.clip(hit, 0, None)]
    return 100.0 * poke.sum() / max(int(inside.sum()), 1)


def around(centre: np.ndarray, front: np.ndarray, azimuth_deg: float) -> Camera:
    a = np.radians(azimuth_deg)
    v = np.array([front[0] * np.cos(a) - front[1] * np.sin(a), front[0] * np.sin(a) + front[1] * np.cos(a), 0.0])
    return Camera.look_at(centre + 3.2 * v, centre, width=320, height=512, fov_y_deg=35)


def measure(run: Path, clearance: float, frame: int, walk: bool) -> tuple[list[int], list[float]]:
    t = RunFolder(run).resume()
    model = t.state.model
    if model.layer is None:
        raise SystemExit(f"{run}: the avatar has no garment layer")
    model.config.garment_clearance = clearance
    under = np.isin(np.asarray(model.parts()), [PART_INDEX[p] for p in UNDER])
    if walk:
        body = t.scene.body_model()
        poses = [t.state.posed_at(p) for p in novel_pose_sequence(body, "walk", 8, base=t.scene.frames[0].pose)]
        azimuths = [0, 90, 180, 270]
        front = np.array([0.0, -1.0, 0.0])  # the body's front (canonical -Y)
    else:
        poses = [t.state.posed(frame)]
        azimuths = list(range(0, 360, 45))
        cam = t.scene.frames[frame].camera
        eye = -cam.R.T @ cam.t
    shares = np.zeros((len(poses), len(azimuths)))
    for i, posed in enumerate(poses):
        centre = posed.means.detach().double().numpy().mean(0)
        if not walk:
            front = eye - centre
            front[2] = 0
            front /= np.linalg.norm(front)
        for j, az in enumerate(azimuths):
            shares[i, j] = poke_through(posed, under, model.num_body, around(centre, front, az))
    return azimuths, shares.mean(0).tolist()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--walk", action="store_true")
    ap.add_argument("--clearance", type=float, default=0.005)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    header = None
    for run in args.runs:
        for clearance in (args.clearance, 0.0):
            azimuths, shares = measure(run, clearance, args.frame, args.walk)
            if header is None:
                header = f"{'run':<28} {'clearance':>9} " + " ".join(f"{a:>5}°" for a in azimuths) + f" {'mean %':>7}"
                print(header)
            print(f"{run.name:<28} {clearance:>9.3f} " + " ".join(f"{s:6.2f}" for s in shares)
                  + f" {np.mean(shares):7.2f}")


if __name__ == "__main__":
    main()
