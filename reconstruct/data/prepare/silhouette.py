"""Exact binary silhouette of a triangle mesh (pixel centres inside any projected triangle)."""

from __future__ import annotations

import numpy as np

from ...camera import Camera


def mesh_silhouette(vertices: np.ndarray, faces: np.ndarray, camera: Camera, *, chunk: int = 4096) -> np.ndarray:
    """(H,W) bool: pixels whose centre (j + 0.5, i + 0.5) lies in the projection of a triangle of the
    mesh ``vertices`` (V,3) world, ``faces`` (F,3), seen by ``camera``. Triangles with a vertex behind
    the near plane are skipped."""
    W, H = camera.width, camera.height
    uv, z = camera.project(np.asarray(vertices, np.float64))
    ok = np.all(z[faces] > camera.near, axis=1)
    tri = uv[faces[ok]]  # (F,3,2)
    lo = np.floor(tri.min(1) - 0.5).astype(np.int64)
    hi = np.ceil(tri.max(1) - 0.5).astype(np.int64)
    inside_img = (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] < W) & (lo[:, 1] < H)
    tri, lo, hi = tri[inside_img], np.maximum(lo[inside_img], 0), np.minimum(hi[inside_img], [W - 1, H - 1])
    out = np.zeros(H * W, bool)
    size = hi - lo + 1
    # group triangles by their box size so every group is one dense array of candidate pixels
    span = np.maximum(size[:, 0], size[:, 1])
    for s in np.unique(np.minimum(2 ** np.ceil(np.log2(np.maximum(span, 1))).astype(np.int64), max(W, H))):
        sel = np.nonzero(np.minimum(2 ** np.ceil(np.log2(np.maximum(span, 1))).astype(np.int64), max(W, H)) == s)[0]
        oy, ox = np.mgrid[0:s, 0:s]
        oy, ox = oy.reshape(-1), ox.reshape(-1)
        for start in range(0, len(sel), max(1, chunk // int(s * s) or 1)):
            idx = sel[start:start + max(1, chunk // int(s * s) or 1)]
            px = lo[idx, 0:1] + ox[None]  # (n,s*s)
            py = lo[idx, 1:2] + oy[None]
            valid = (px <= hi[idx, 0:1]) & (py <= hi[idx, 1:2])
            cx, cy = px + 0.5, py + 0.5
            a, b, c = tri[idx, 0], tri[idx, 1], tri[idx, 2]

            def edge(p, q):
                return (q[:, 0:1] - p[:, 0:1]) * (cy - p[:, 1:2]) - (q[:, 1:2] - p[:, 1:2]) * (cx - p[:, 0:1])

            e0, e1, e2 = edge(a, b), edge(b, c), edge(c, a)
            hit = valid & (((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0)))
            out[(py[hit] * W + px[hit])] = True
    return out.reshape(H, W)
