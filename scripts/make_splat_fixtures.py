"""Writes the splat-format fixtures of ``tests/data/splats`` with PlayCanvas's ``splat-transform``,
the independent reference for SuperSplat's compressed ``.ply``, Niantic's ``.spz`` (through
Niantic's own library, which it bundles) and antimatter15's ``.splat``.

Needs Node.js and ``npm install @playcanvas/splat-transform@3.7.0`` in a folder given as
``--tool-dir`` (not a project dependency: the tests read only the files this writes):

    python scripts/make_splat_fixtures.py --tool-dir /path/with/node_modules

1. ``source.ply``: 300 Gaussians (two of the compressed format's 256-blocks) with random means,
   log-scales, rotations, opacities, colours and degree-1 SH, written here as a plain 3DGS PLY.
2. splat-transform converts it to ``source.compressed.ply``, ``source.spz`` (version 4, zstd),
   ``source_v3.spz`` (gzip) and ``source.sog`` (SOG version 2, WebP images in a zip); the project's encoders write ``source.splat``, ``ours.compressed.ply``,
   ``ours_v3.spz``, ``ours_v4.spz`` and ``ours.sog`` from it.
3. splat-transform decodes each of them back to a plain PLY (``source_spz.decoded.ply`` ...): what
   the tests compare the project's readers with.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "tests" / "data" / "splats"
N = 300
WRITTEN = ("ours.compressed.ply", "ours_v3.spz", "ours_v4.spz", "ours.sog")  # by the project's encoders
DECODED = {name: name.replace(".", "_") + ".decoded.ply"
           for name in ("source.compressed.ply", "source.spz", "source_v3.spz", "source.splat", "source.sog") + WRITTEN}


def write_source(path: Path, seed: int = 4) -> None:
    rng = np.random.default_rng(seed)
    names = ["x", "y", "z"] + [f"f_dc_{k}" for k in range(3)] + [f"f_rest_{k}" for k in range(9)] + \
        ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    q = rng.normal(size=(N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    cols = np.concatenate([
        rng.uniform(-1, 1, (N, 3)) * np.array([0.4, 0.3, 0.9]),
        rng.uniform(-1.6, 1.6, (N, 3)),  # f_dc: colours 0.05-0.95
        rng.uniform(-0.9, 0.9, (N, 9)),  # f_rest, degree 1
        rng.uniform(-3.0, 4.5, (N, 1)),  # opacity logits
        rng.uniform(-6.0, -2.5, (N, 3)),  # log standard deviations
        q,
    ], 1).astype("<f4")
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {N}\n" + \
        "".join(f"property float {n}\n" for n in names) + "end_header\n"
    path.write_bytes(header.encode() + cols.tobytes())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--tool-dir", required=True, help="a folder with node_modules/@playcanvas/splat-transform")
    args = ap.parse_args()
    from reconstruct.compressed_ply import encode_compressed_ply
    from reconstruct.ply import read_gaussians_ply
    from reconstruct.splat_file import encode_splat
    from reconstruct.sog import encode_sog
    from reconstruct.spz import encode_spz

    def tool(*argv):
        subprocess.run(["npx", "--no-install", "splat-transform", "-q", "-w", *argv], check=True, cwd=args.tool_dir)

    OUT.mkdir(parents=True, exist_ok=True)
    src = OUT / "source.ply"
    write_source(src)
    tool(str(src), str(OUT / "source.compressed.ply"))
    tool(str(src), str(OUT / "source.spz"))
    tool("--spz-version", "3", str(src), str(OUT / "source_v3.spz"))
    tool("-g", "cpu", str(src), str(OUT / "source.sog"))  # SOG's k-means on the CPU
    g = read_gaussians_ply(src)
    arrays = (g.means, g.scales, g.rotations, g.opacities, g.colors)
    (OUT / "source.splat").write_bytes(encode_splat(*arrays))
    (OUT / "ours.compressed.ply").write_bytes(encode_compressed_ply(*arrays))
    (OUT / "ours_v3.spz").write_bytes(encode_spz(*arrays, version=3))
    (OUT / "ours_v4.spz").write_bytes(encode_spz(*arrays, version=4))
    (OUT / "ours.sog").write_bytes(encode_sog(*arrays))
    for name in DECODED:
        tool(str(OUT / name), str(OUT / DECODED[name]))
    print(sorted(p.name for p in OUT.iterdir()))


if __name__ == "__main__":
    main()
