"""UV positional maps: per valid texel of the body's UV atlas, the canonical surface point.

A texel is valid when its centre lies inside a UV triangle and not on an excluded inner surface
(mouth/eye cavities, eyes, tongue). Texel (row r, column c) of an R x R map has its centre at
u = (c + 0.5) / R, v = 1 - (r + 0.5) / R (v up, row 0 at the top of the atlas image).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .base import BodyModel
from .lbs import safe_normalize
from .parts import PART_INDEX, part_of_bone
from .pose import BodyPose


@dataclass
class UVMap:
    """The canonical positional map of a body at one resolution (N valid texels)."""

    resolution: int
    mask: np.ndarray  # (R,R) bool
    texel_rc: np.ndarray  # (N,2) int64 row, column
    face: np.ndarray  # (N,) int64 triangle index
    bary: np.ndarray  # (N,3) float64 barycentric coordinates in that triangle
    positions: torch.Tensor  # (N,3) float64 canonical position
    normals: torch.Tensor  # (N,3) float64 canonical unit normal
    weights: torch.Tensor  # (N,J) float64 skinning weights, rows sum to 1
    parts: np.ndarray  # (N,) int64 body-part index (reconstruct.body.parts)

    def __len__(self) -> int:
        return int(self.texel_rc.shape[0])

    def scatter(self, values: torch.Tensor, fill: float = 0.0) -> torch.Tensor:
        """Per-texel values (N,C) to a (C,R,R) image (``fill`` outside the valid texels)."""
        R = self.resolution
        out = torch.full((values.shape[1], R * R), fill, dtype=values.dtype, device=values.device)
        flat = torch.as_tensor(self.texel_rc[:, 0] * R + self.texel_rc[:, 1], device=values.device)
        out[:, flat] = values.T
        return out.reshape(-1, R, R)


def _rasterize_uv(uv_tri: np.ndarray, R: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Texels whose centres fall in each UV triangle: (face, row, col, barycentrics)."""
    # triangle corners in continuous texel coordinates (x = column, y = row)
    x = uv_tri[..., 0] * R - 0.5
    y = (1.0 - uv_tri[..., 1]) * R - 0.5
    cmin = np.clip(np.floor(x.min(1)), 0, R - 1).astype(np.int64)
    cmax = np.clip(np.ceil(x.max(1)), 0, R - 1).astype(np.int64)
    rmin = np.clip(np.floor(y.min(1)), 0, R - 1).astype(np.int64)
    rmax = np.clip(np.ceil(y.max(1)), 0, R - 1).astype(np.int64)
    nx, ny = cmax - cmin + 1, rmax - rmin + 1
    counts = nx * ny
    face = np.repeat(np.arange(len(uv_tri)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    col = cmin[face] + local % nx[face]
    row = rmin[face] + local // nx[face]
    # barycentrics of the texel centre
    x0, x1, x2 = x[face, 0], x[face, 1], x[face, 2]
    y0, y1, y2 = y[face, 0], y[face, 1], y[face, 2]
    det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
    ok = np.abs(det) > 1e-14
    det = np.where(ok, det, 1.0)
    b0 = ((y1 - y2) * (col - x2) + (x2 - x1) * (row - y2)) / det
    b1 = ((y2 - y0) * (col - x2) + (x0 - x2) * (row - y2)) / det
    b2 = 1.0 - b0 - b1
    eps = -1e-9
    inside = ok & (b0 >= eps) & (b1 >= eps) & (b2 >= eps)
    bary = np.stack([b0, b1, b2], 1)[inside]
    face, row, col = face[inside], row[inside], col[inside]
    # a texel on a shared edge belongs to the first triangle that claims it
    _, first = np.unique(row * R + col, return_index=True)
    bary = np.clip(bary[first], 0.0, 1.0)
    bary /= bary.sum(1, keepdims=True)
    return face[first], row[first], col[first], bary


def build_uv_map(body: BodyModel, resolution: int) -> UVMap:
    """The canonical positional UV map of ``body`` at ``resolution`` x ``resolution``."""
    if int(resolution) < 8:
        raise ValueError(f"UV map resolution must be at least 8, found {resolution}")
    R = int(resolution)
    uv = body.uv_coords.numpy()
    uv_tri = uv[body.face_uv_indices.numpy()]  # (F,3,2)
    face, row, col, bary = _rasterize_uv(uv_tri, R)
    uv_points = np.einsum("nk,nkd->nd", bary, uv_tri[face])
    keep = ~body.excluded_uv(uv_points)
    face, row, col, bary = face[keep], row[keep], col[keep], bary[keep]

    tri = body.faces.numpy()[face]  # (N,3) vertex indices
    b = torch.as_tensor(bary)
    verts = body.canonical_vertices
    positions = (b[:, :, None] * verts[torch.as_tensor(tri)]).sum(1)
    normals = safe_normalize((b[:, :, None] * body.canonical_normals[torch.as_tensor(tri)]).sum(1))
    weights = (b[:, :, None] * body.skin_weights[torch.as_tensor(tri)]).sum(1)
    weights = weights / weights.sum(1, keepdim=True)
    bone_part = np.array([PART_INDEX[part_of_bone(name)] for name in body.bone_labels])
    parts = bone_part[weights.argmax(1).numpy()]
    mask = np.zeros((R, R), bool)
    mask[row, col] = True
    return UVMap(R, mask, np.stack([row, col], 1), face, bary, positions, normals, weights, parts)


def posed_position_map(body: BodyModel, uv_map: UVMap, pose: BodyPose, *, include_global: bool = False) -> torch.Tensor:
    """(3,R,R) float32 map of the posed surface at each valid texel (zeros elsewhere): the pose
    encoder's input (paper Eq. 13). Without ``include_global`` the global rotation and translation
    are left out, so the map encodes only the articulation."""
    if not include_global:
        pose = BodyPose(pose.joint_rotations, np.zeros(3), np.zeros(3))
    skin = body.skinning(uv_map.weights)
    posed, _ = skin(body.bone_transforms(pose), uv_map.positions)
    return uv_map.scatter(posed.to(torch.float32))


def texel_neighbours(texel_rc: np.ndarray, resolution: int) -> np.ndarray:
    """(N,4) indices of each texel's valid 4-neighbours in the UV grid, -1 where none."""
    R = resolution
    index = np.full((R, R), -1, np.int64)
    index[texel_rc[:, 0], texel_rc[:, 1]] = np.arange(len(texel_rc))
    out = np.full((len(texel_rc), 4), -1, np.int64)
    r, c = texel_rc[:, 0], texel_rc[:, 1]
    for k, (dr, dc) in enumerate(((0, 1), (1, 0), (0, -1), (-1, 0))):
        rr, cc = r + dr, c + dc
        ok = (rr >= 0) & (rr < R) & (cc >= 0) & (cc < R)
        out[ok, k] = index[rr[ok], cc[ok]]
    return out


def texel_spacing(uv_map: UVMap) -> torch.Tensor:
    """(N,) mean 3D distance from each valid texel's canonical point to its valid 4-neighbours in
    the map (a natural isotropic Gaussian scale); texels without a valid neighbour get the median."""
    pos = uv_map.positions
    total = torch.zeros(len(uv_map), dtype=pos.dtype)
    count = torch.zeros(len(uv_map), dtype=pos.dtype)
    for nb in texel_neighbours(uv_map.texel_rc, uv_map.resolution).T:
        valid = torch.as_tensor(nb >= 0)
        total[valid] += (pos[valid] - pos[torch.as_tensor(nb[nb >= 0])]).norm(dim=1)
        count[valid] += 1
    spacing = total / count.clamp_min(1)
    # chart borders can neighbour a far-away chart in the atlas: cap at 3x the median
    med = spacing[count > 0].median()
    spacing = torch.where(count > 0, torch.minimum(spacing, 3 * med), med)
    return spacing


def texel_frames(uv_map: UVMap) -> tuple[torch.Tensor, torch.Tensor]:
    """Per valid texel, the surface's tangent frame as the UV grid lays it out: (N,3) unit tangent
    ``t_u`` along the map's columns (+u), projected into the plane of the canonical normal, and
    (N,2) the 3D lengths of one texel step along u and along v (the local texel spacing in each
    direction: the footprint a flat Gaussian needs to meet its neighbours).

    Steps are central differences over the valid 4-neighbours (one-sided at chart borders). Chart
    borders can neighbour a far-away chart in the atlas: a step longer than 3x the median is
    dropped; a texel without a usable step in a direction gets its isotropic ``texel_spacing`` and,
    for u, a tangent built from the normal."""
    pos, nrm = uv_map.positions, uv_map.normals
    nb = torch.as_tensor(texel_neighbours(uv_map.texel_rc, uv_map.resolution))  # (+u, +row, -u, -row)
    iso = texel_spacing(uv_map)
    med = iso.median()
    steps = []
    for plus, minus, sign in ((0, 2, 1.0), (3, 1, 1.0)):  # u: columns; v: rows upwards (v = 1 - row / R)
        total = torch.zeros_like(pos)
        count = torch.zeros(len(pos), dtype=pos.dtype)
        for k, s in ((plus, sign), (minus, -sign)):
            idx = nb[:, k]
            ok = idx >= 0
            d = torch.zeros_like(pos)
            d[ok] = s * (pos[idx[ok]] - pos[ok])
            ok = ok & (d.norm(dim=1) <= 3 * med)
            total[ok] += d[ok]
            count[ok] += 1
        steps.append((total / count.clamp_min(1)[:, None], count > 0))
    (du, has_u), (dv, has_v) = steps
    # tangent along u in the normal's plane; fallback: any direction perpendicular to the normal
    t = du - (du * nrm).sum(1, keepdim=True) * nrm
    good = has_u & (t.norm(dim=1) > 1e-3 * med)
    helper = torch.where((nrm[:, 2:3].abs() < 0.9), torch.tensor([0.0, 0.0, 1.0], dtype=pos.dtype),
                         torch.tensor([1.0, 0.0, 0.0], dtype=pos.dtype))
    fallback = torch.linalg.cross(helper, nrm)
    t = torch.where(good[:, None], t, fallback)
    t = safe_normalize(t)
    lu = torch.where(good, du.norm(dim=1), iso)
    lv = torch.where(has_v & (dv.norm(dim=1) > 1e-3 * med), dv.norm(dim=1), iso)
    return t, torch.stack([lu, lv], 1)
