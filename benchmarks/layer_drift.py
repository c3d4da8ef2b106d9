"""How far a trained avatar's Gaussians slide over the surface they draw from frame to frame: a
texture that lands a few millimetres apart in each training frame is learned as its average, so
drift blurs even what the camera sees.

    OMP_NUM_THREADS=1 python benchmarks/layer_drift.py RUN [RUN ...] [--every 5] [--sample 6]

For a synthetic loose-clothing scene the Gaussians are the garment layer's (opacity > 0.5) and the
surface is the benchmark's garment mesh, posed with its own skinning (``pose_garment``); for a
tight scene they are the body Gaussians on the legs (thighs and shins) and the surface is the body
mesh. Each Gaussian is attached, in the first frame used, to the nearest point of a dense sample
of the surface (``--sample`` subdivisions per triangle edge), kept as a triangle and barycentric
coordinates. In every frame used (every ``--every``-th training frame, the avatar posed as it
renders that frame) its offset from that material point is read in the triangle's own frame
(an in-plane part and a normal part). The drift of a Gaussian is the RMS over frames of its
in-plane offset's deviation from its mean (a constant offset is a shifted texture, not a blur);
the table gives the median and the 90th percentile over Gaussians, and the same for the normal
part, in millimetres.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LEG_PARTS = ("thigh.L", "shin.L", "thigh.R", "shin.R")


def surface_samples(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(S,) triangle ids and (S,3) barycentric coordinates of a grid of ``n`` subdivisions per
    edge on every triangle of ``faces``."""
    if n < 1:
        raise ValueError(f"surface sample: at least 1 subdivision per edge, found {n}")
    ij = np.array([(i, j) for i in range(n + 1) for j in range(n + 1 - i)], np.float64) / n
    bary = np.column_stack([1 - ij.sum(1), ij[:, 0], ij[:, 1]])
    F = len(faces)
    return np.repeat(np.arange(F), len(bary)), np.tile(bary, (F, 1))


def material_points(vertices: np.ndarray, faces: np.ndarray, face_id: np.ndarray, bary: np.ndarray) -> np.ndarray:
    tri = vertices[faces[face_id]]  # (G,3,3)
    return np.einsum("gk,gkd->gd", bary, tri)


def attach(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Each of ``points`` (G,3) to the nearest sample of the surface: (G,) triangle ids, (G,3) barycentric."""
    fid, bary = surface_samples(faces, n)
    _, k = cKDTree(material_points(vertices, faces, fid, bary)).query(points)
    return fid[k], bary[k]


def drift(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, face_id: np.ndarray,
          bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(G,) in-plane and (G,) normal drift of Gaussians at ``points`` (F,G,3) over F frames of a
    surface at ``vertices`` (F,V,3), each attached to (``face_id``, ``bary``): the RMS over frames of
    the offset's deviation from its mean, in the attached triangle's frame (module docstring)."""
    points, vertices = np.asarray(points, np.float64), np.asarray(vertices, np.float64)
    inplane, normal = [], []
    for p, v in zip(points, vertices):
        tri = v[faces[face_id]]
        d = p - material_points(v, faces, face_id, bary)
        e1 = tri[:, 1] - tri[:, 0]
        nrm = np.cross(e1, tri[:, 2] - tri[:, 0])
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        e2 = np.cross(nrm, e1)
        inplane.append(np.stack([(d * e1).sum(1), (d * e2).sum(1)], 1))
        normal.append((d * nrm).sum(1))
    t, c = np.stack(inplane), np.stack(normal)  # (F,G,2), (F,G)
    t_dev = np.sqrt(((t - t.mean(0)) ** 2).sum(2).mean(0))
    c_dev = np.sqrt(((c - c.mean(0)) ** 2).mean(0))
    return t_dev, c_dev


@torch.no_grad()
def run_drift(run: Path, every: int = 5, n: int = 6) -> dict:
    from reconstruct.body.parts import PART_INDEX
    from reconstruct.data.synthetic.garment_skinning import pose_garment
    from reconstruct.data.synthetic.generator import loose_outfit_of
    from reconstruct.run_folder import RunFolder

    trainer = RunFolder(run).resume()
    state, scene = trainer.state, trainer.scene
    if scene.meta.get("source") != "synthetic":
        raise ValueError(f"{run}: layer drift needs a synthetic scene (its surface is known), found {scene.name!r}")
    model = state.model
    outfit = loose_outfit_of(scene)
    frames = scene.frames[::every]
    if outfit is not None:
        if model.num_layer == 0:
            raise ValueError(f"{run}: a loose-clothing scene trained without a garment layer")
        pick = model.num_body + torch.nonzero(model.opacities()[model.num_body:] > 0.5)[:, 0].numpy()
        faces = outfit.garment.faces
        surface = [pose_garment(outfit.body, outfit.garment, outfit.weights, f.pose) for f in frames]
        what = "garment layer / garment mesh"
    else:
        parts = model.parts()[: model.num_body]
        pick = np.flatnonzero(np.isin(parts, [PART_INDEX[p] for p in LEG_PARTS]))
        faces = state.body.faces.numpy()
        surface = [state.body.posed_vertices(f.pose).numpy() for f in frames]
        what = "body legs / body mesh"
    points = np.stack([state.posed(f.index).means[pick].numpy() for f in frames])
    fid, bary = attach(points[0], surface[0], faces, n)
    t, c = drift(points, np.stack(surface), faces, fid, bary)
    return {"what": what, "gaussians": len(pick), "frames": len(frames),
            "inplane_median_mm": 1e3 * float(np.median(t)), "inplane_p90_mm": 1e3 * float(np.percentile(t, 90)),
            "normal_median_mm": 1e3 * float(np.median(c)), "normal_p90_mm": 1e3 * float(np.percentile(c, 90))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--every", type=int, default=5, help="use every N-th training frame")
    p.add_argument("--sample", type=int, default=6, help="surface sample: subdivisions per triangle edge")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    print("| run | Gaussians (what) | frames | in-plane drift median / p90 | normal drift median / p90 |")
    print("|---|---|---|---|---|")
    for run in args.runs:
        r = run_drift(run, args.every, args.sample)
        print(f"| {run.name} | {r['gaussians']:,} ({r['what']}) | {r['frames']} | {r['inplane_median_mm']:.1f} / "
              f"{r['inplane_p90_mm']:.1f} mm | {r['normal_median_mm']:.1f} / {r['normal_p90_mm']:.1f} mm |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
