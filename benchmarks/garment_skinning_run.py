"""Stage I of a synthetic loose-clothing scene with the garment layer skinned exactly as the
scene's cloth: what perfect layer skinning is worth (a measurement, not a training mode).

    OMP_NUM_THREADS=1 python benchmarks/garment_skinning_run.py train --scene "synthetic:seed=0,clothing=wide_trousers" \\
        --out RUN --stage 1 --iters 800 --threads 1 --set threads=1 --set lr_layer_skinning=0

The arguments are ``wonderhuman-studio``'s. When training builds its garment layer, each layer
Gaussian's built skinning weights are replaced by the benchmark garment mesh's own weights
(``garment_skinning.garment_weights``, which pose the cloth the images show) at the nearest point
of a dense sample of the canonical garment mesh (barycentric, as ``layer_drift.py`` attaches), so
that the layer follows the cloth as closely as LBS can; give ``lr_layer_skinning=0`` to keep them.
Score the run with ``eval`` and ``benchmarks/layer_drift.py`` against one trained the same way
with the built weights. The layer's checkpointed weights are the replaced ones, so the run
evaluates, resumes and exports like any other.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.layer_drift import attach  # noqa: E402


def garment_weights_at(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray,
                       n: int = 6) -> np.ndarray:
    """(G,J) the skinning weights of a mesh (``vertices`` (V,3), ``faces``, per-vertex ``weights``
    (V,J)) at the nearest surface sample (``n`` subdivisions per triangle edge) to each of
    ``points`` (G,3), interpolated barycentrically; rows sum to 1 when the vertices' do."""
    if weights.shape[0] != len(vertices):
        raise ValueError(f"garment weights: {weights.shape[0]} rows for {len(vertices)} vertices")
    fid, bary = attach(np.asarray(points, np.float64), vertices, faces, n)
    return np.einsum("gk,gkj->gj", bary, weights[faces[fid]])


def main(argv=None) -> int:
    import reconstruct.train.trainer as trainer_module
    from app.cli import main as cli_main
    from reconstruct.data.load import load_scene
    from reconstruct.data.synthetic.generator import loose_outfit_of

    argv = list(sys.argv[1:] if argv is None else argv)
    if "--scene" not in argv:
        raise SystemExit("garment_skinning_run: give --scene with a synthetic loose-clothing scene")
    spec = argv[argv.index("--scene") + 1]
    outfit = loose_outfit_of(load_scene(spec, progress=False))
    if outfit is None:
        raise SystemExit(f"garment_skinning_run: {spec!r} is not a synthetic loose-clothing scene")
    built = trainer_module.garment_layer_for

    def with_garment_weights(*args, **kwargs):
        layer = built(*args, **kwargs)
        if layer is None:
            return None
        g = outfit.garment
        w = garment_weights_at(layer.positions.double().numpy(), g.vertices, g.faces, outfit.weights)
        change = np.abs(w - layer.weights.double().numpy()).sum(1)
        print(f"garment layer: skinning weights replaced by the garment mesh's (L1 change median "
              f"{np.median(change):.3f}, p90 {np.percentile(change, 90):.3f})", file=sys.stderr)
        layer.weights = torch.as_tensor(w, dtype=layer.weights.dtype)
        return layer

    trainer_module.garment_layer_for = with_garment_weights
    try:
        return cli_main(argv)
    finally:
        trainer_module.garment_layer_for = built


if __name__ == "__main__":
    sys.exit(main())
