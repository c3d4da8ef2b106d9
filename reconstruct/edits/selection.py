"""Selections: (N,) bool texel masks, one entry per Gaussian (Gaussians are the UV map's valid
texels, ``model.uv_map.texel_rc``, then -- with a garment layer -- the layer's grid points).

- ``part_mask``: by body part (``reconstruct/body/parts.py`` names, and ``garment`` for a garment
  layer's Gaussians; shell patterns like ``*.L``, ``upperarm.*``, and ``arms`` / ``legs`` /
  ``hands`` / ``feet``).
- ``screen_mask``: the Gaussians inside a screen region (rectangle, brush, lasso polygon) seen by a
  camera, from a ``Snapshot`` (what the studio shows: any pose, observation or canonical space):
  the visible surface only (the rasterizer's first-hit ids) or through the body (every Gaussian
  whose centre projects inside).
- ``grow`` / ``shrink``: by texels over the UV grid's 4-neighbourhood (``AvatarModel.neighbours``: the
  body's ``texel_neighbours``, a garment layer's own grid).
"""

from __future__ import annotations

import fnmatch

import numpy as np
import torch

from ..avatar.garment_layer import AVATAR_PART_NAMES

GROUPS = {"arms": ("upperarm.*", "lowerarm.*", "hand.*"), "legs": ("thigh.*", "shin.*", "foot.*"),
          "hands": ("hand.*",), "feet": ("foot.*",), "body": ("*",)}


def part_mask(parts: np.ndarray, names: str | list[str]) -> np.ndarray:
    """Gaussians whose part label (``model.parts()``) matches any of ``names`` (comma-separated
    or a list; shell patterns allowed)."""
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    wanted: set[int] = set()
    for n in names:
        pats = GROUPS.get(n, (n,))
        hits = {i for i, p in enumerate(AVATAR_PART_NAMES) for pat in pats if fnmatch.fnmatchcase(p, pat)}
        if not hits:
            raise ValueError(f"part {n!r}: no body part matches (parts: {', '.join(AVATAR_PART_NAMES)}; "
                             f"groups: {', '.join(GROUPS)})")
        wanted |= hits
    return np.isin(np.asarray(parts), sorted(wanted))


# ----- screen regions (bool images) --------------------------------------------------------------
def rect_region(width: int, height: int, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """Pixels whose centres lie in the rectangle between the corners (either order)."""
    xa, xb = sorted((x0, x1))
    ya, yb = sorted((y0, y1))
    xs = np.arange(width) + 0.5
    ys = np.arange(height) + 0.5
    return ((ys >= ya) & (ys <= yb))[:, None] & ((xs >= xa) & (xs <= xb))[None, :]


def brush_region(width: int, height: int, points, radius: float) -> np.ndarray:
    """Pixels within ``radius`` of a stroke through ``points`` ((K,2) x, y; segments between
    consecutive points are filled)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    out = np.zeros((height, width), bool)
    segs = [(pts[i], pts[i + 1]) for i in range(len(pts) - 1)] or [(pts[0], pts[0])]
    for a, b in segs:
        d = b - a
        L2 = float(d @ d)
        t = np.zeros_like(xx) if L2 == 0 else np.clip(((xx - a[0]) * d[0] + (yy - a[1]) * d[1]) / L2, 0, 1)
        out |= (xx - a[0] - t * d[0]) ** 2 + (yy - a[1] - t * d[1]) ** 2 <= radius ** 2
    return out


def points_in_polygon(x: np.ndarray, y: np.ndarray, polygon) -> np.ndarray:
    """Even-odd rule: whether points (x, y) lie inside ``polygon`` ((K,2), closed implicitly)."""
    poly = np.asarray(polygon, np.float64).reshape(-1, 2)
    if len(poly) < 3:
        raise ValueError(f"a lasso needs at least 3 points, found {len(poly)}")
    inside = np.zeros(np.shape(x), bool)
    xj, yj = poly[-1]
    for xi, yi in poly:
        crosses = (yi > y) != (yj > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = (xj - xi) * (y - yi) / (yj - yi) + xi
        inside ^= crosses & (x < xc)
        xj, yj = xi, yi
    return inside


def lasso_region(width: int, height: int, polygon) -> np.ndarray:
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    return points_in_polygon(xx, yy, polygon)


# ----- from a region to Gaussians ----------------------------------------------------------------
def snapshot_first_hit(snapshot, camera, hit_threshold: float = 0.5) -> np.ndarray:
    """(H,W) int: the snapshot row first hit by each pixel's ray (-1: none), by the training
    rasterizer."""
    from ..raster import rasterization

    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32)  # noqa: E731
    if len(snapshot) == 0:
        return np.full((camera.height, camera.width), -1, np.int64)
    out = rasterization(t(snapshot.means), t(snapshot.rotations), t(snapshot.scales), t(snapshot.opacities),
                        t(snapshot.colors), camera, return_first_hit=True, hit_threshold=hit_threshold)
    return np.asarray(out.first_hit.cpu())


def rows_to_gaussians(snapshot, rows: np.ndarray, num_gaussians: int) -> np.ndarray:
    """(N,) mask of the Gaussians behind snapshot ``rows`` (snapshots of an edited avatar leave
    erased Gaussians out; ``snapshot.ids`` maps rows to Gaussians)."""
    ids = getattr(snapshot, "ids", None)
    g = np.asarray(rows, np.int64) if ids is None else np.asarray(ids)[np.asarray(rows, np.int64)]
    mask = np.zeros(num_gaussians, bool)
    mask[g] = True
    return mask


def screen_mask(snapshot, camera, region: np.ndarray, num_gaussians: int, *, through: bool = False,
                first_hit: np.ndarray | None = None) -> np.ndarray:
    """Gaussians in the screen ``region`` ((H,W) bool for ``camera``): visible surface only (first
    hits; pass ``first_hit`` to reuse one render for several strokes) or ``through`` the body."""
    region = np.asarray(region, bool)
    if region.shape != (camera.height, camera.width):
        raise ValueError(f"region of shape {region.shape} for a {camera.width}x{camera.height} camera")
    if through:
        uv, z = camera.project(np.asarray(snapshot.means, np.float64))
        ok = (z > camera.near) & np.isfinite(uv).all(1)
        px = np.floor(uv[:, 0]).astype(np.int64, copy=False)
        py = np.floor(uv[:, 1]).astype(np.int64, copy=False)
        ok &= (px >= 0) & (px < camera.width) & (py >= 0) & (py < camera.height)
        ok &= np.asarray(snapshot.opacities) > 0
        rows = np.flatnonzero(ok)
        rows = rows[region[py[rows], px[rows]]]
    else:
        hits = snapshot_first_hit(snapshot, camera) if first_hit is None else first_hit
        rows = np.unique(hits[region & (hits >= 0)])
    return rows_to_gaussians(snapshot, rows, num_gaussians)


# ----- over the UV grid -------------------------------------------------------------------------
def grow(mask: np.ndarray, neighbours: np.ndarray, texels: int = 1) -> np.ndarray:
    """``mask`` grown by ``texels`` over the UV grid's 4-neighbourhood (``texel_neighbours``)."""
    m = np.asarray(mask, bool).copy()
    for _ in range(texels):
        hit = np.where(neighbours >= 0, m[np.maximum(neighbours, 0)], False).any(1)
        m |= hit
    return m


def shrink(mask: np.ndarray, neighbours: np.ndarray, texels: int = 1) -> np.ndarray:
    """``mask`` shrunk by ``texels``: a texel stays when all its grid neighbours are selected
    (texels on the atlas border count missing neighbours as selected)."""
    m = np.asarray(mask, bool).copy()
    for _ in range(texels):
        m &= np.where(neighbours >= 0, m[np.maximum(neighbours, 0)], True).all(1)
    return m
