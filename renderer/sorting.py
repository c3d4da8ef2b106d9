"""Back-to-front depth order of the splats, recomputed only when the view or the data changed.

``depth_order`` quantises camera depth to an unsigned integer key (16 bits by default; 32 bits
as two stable 16-bit passes, LSD radix style) and lets numpy's stable argsort do the work: for
16-bit keys numpy uses a radix sort, ~1-2 ms for 262k keys on this machine against ~25 ms for a
stable sort of float32 depths. Equal keys keep their index order (stable), so the order is
deterministic. With 16 bits, two splats whose depths differ by less than (zmax - zmin) / 65535
may be drawn in index order instead of depth order; for a 2 m deep subject that is 30 µm.

``SortCache`` remembers the last order with the key (data version, the camera's depth row
R[2], t[2] (equal within 1e-9), near, far, key bits): depth order and culling depend on nothing else, so repeated
frames, render-mode and background switches, intrinsics or resolution changes and pans (moving the
camera in its image plane leaves t[2] unchanged) reuse it without sorting again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def depth_order(z: np.ndarray, bits: int = 16) -> np.ndarray:
    """Indices of ``z`` from the largest depth to the smallest (back to front), int64.

    ``z`` must be finite. ``bits`` is 16 (one radix pass) or 32 (two stable passes)."""
    z = np.asarray(z)
    n = z.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    if bits not in (16, 32):
        raise ValueError(f"depth_order: bits must be 16 or 32, found {bits}")
    zmin = float(z.min())
    zmax = float(z.max())
    span = zmax - zmin
    if not np.isfinite(span):
        raise ValueError("depth_order: depths must be finite")
    if span <= 0.0:
        return np.arange(n, dtype=np.int64)
    # back to front = descending depth = ascending (zmax - z)
    if bits == 16:
        key = (np.float32(zmax) - z.astype(np.float32, copy=False)) * np.float32(65535.0 / span)
        return np.argsort(np.clip(key, 0, 65535).astype(np.uint16), kind="stable")
    key = (zmax - z.astype(np.float64, copy=False)) * (4294967295.0 / span)
    key = np.clip(key, 0, 4294967295.0).astype(np.uint32)
    low = np.argsort((key & 0xFFFF).astype(np.uint16), kind="stable")
    high = np.argsort((key[low] >> 16).astype(np.uint16), kind="stable")
    return low[high]


def variance_along(quats: np.ndarray, scales: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Variance ``d^T R S^2 R^T d`` of Gaussians (unit (w,x,y,z) quaternions, std devs) along the
    unit vector ``d`` (float64): sum over local axes k of (s_k * (d . R[:, k]))^2."""
    q = np.asarray(quats, np.float64)
    s = np.asarray(scales, np.float64)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    d0, d1, d2 = (float(v) for v in direction)
    c0 = d0 * (1 - 2 * (y * y + z * z)) + d1 * 2 * (x * y + w * z) + d2 * 2 * (x * z - w * y)
    c1 = d0 * 2 * (x * y - w * z) + d1 * (1 - 2 * (x * x + z * z)) + d2 * 2 * (y * z + w * x)
    c2 = d0 * 2 * (x * z + w * y) + d1 * 2 * (y * z - w * x) + d2 * (1 - 2 * (x * x + y * y))
    return (s[:, 0] * c0) ** 2 + (s[:, 1] * c1) ** 2 + (s[:, 2] * c2) ** 2


@dataclass
class SortResult:
    order: np.ndarray  # ids (into the sanitized arrays) of the splats to draw, back to front
    z: np.ndarray  # camera depth of every sanitized splat (float32)
    behind_camera: int  # mean at or behind the near plane
    near_plane: int  # mean in front of the near plane but its extent along the view reaches it
    beyond_far: int  # mean beyond the far plane
    depth_min: float  # depth range of the splats drawn (for the depth mode)
    depth_max: float


class SortCache:
    """Culls and sorts the splats for a camera; reuses the last result while nothing moved."""

    def __init__(self, bits: int = 16, near_sigma: float = 3.0, tolerance: float = 1e-9):
        self.bits = bits
        self.tolerance = tolerance
        self._view = None
        self.near_sigma = near_sigma
        self._key = None
        self._result: SortResult | None = None
        self.sorts = 0  # number of sorts actually performed (for tests and stats)

    def invalidate(self) -> None:
        self._key = None
        self._result = None

    def get(self, data_key, means_t: np.ndarray, max_scale: np.ndarray, quats: np.ndarray, scales: np.ndarray,
            R: np.ndarray, t: np.ndarray, near: float, far: float) -> tuple[SortResult, bool]:
        """Back-to-front order of the splats in front of the camera ``(R, t)``.

        ``means_t`` (3,N) float32 (structure of arrays: elementwise numpy beats a BLAS matvec on
        a busy 2-core machine), ``max_scale`` (N,) the largest standard deviation of each splat,
        ``quats`` (N,4) unit (w,x,y,z) and ``scales`` (N,3) describe the sanitized splats;
        ``data_key`` changes whenever they do. Returns the result and whether a sort
        happened."""
        row = np.asarray(R, np.float64)[2].copy()
        tz = float(np.asarray(t, np.float64)[2])
        key = (data_key, float(near), float(far), self.bits, self.near_sigma)
        if self._result is not None and key == self._key and self._same_view(row, tz):
            return self._result, False
        result = self._compute(means_t, max_scale, quats, scales, row, tz, float(near), float(far))
        self._key = key
        self._view = (row, tz)
        self._result = result
        self.sorts += 1
        return result, True

    def _same_view(self, row: np.ndarray, tz: float) -> bool:
        # rebuilding a camera from moved eye and target (a pan) rounds differently: tolerate
        # changes far below anything that could reorder splats
        prow, ptz = self._view
        return bool(np.max(np.abs(row - prow)) <= self.tolerance and abs(tz - ptz) <= self.tolerance * (1.0 + abs(ptz)))

    def _compute(self, means_t, max_scale, quats, scales, row, tz, near, far) -> SortResult:
        n = means_t.shape[1]
        if n == 0:
            return SortResult(np.zeros(0, np.uint32), np.zeros(0, np.float32), 0, 0, 0, 0.0, 1.0)
        r0, r1, r2 = (np.float32(v) for v in row)
        z = means_t[0] * r0
        z += means_t[1] * r1
        z += means_t[2] * r2
        z += np.float32(tz)
        behind = ~(z > near)
        beyond = ~behind & ~(z < far)
        # near-plane crossing: the splat's extent along the view direction, near_sigma * sigma_z,
        # reaches the near plane. sigma_z <= the largest scale, so only those candidates need
        # the exact sigma_z = sqrt(r^T Sigma r).
        cand = np.flatnonzero(~behind & ~beyond & (z - np.float32(self.near_sigma) * max_scale <= near))
        crossing_ids = cand[:0]
        if cand.size:
            var_z = variance_along(quats[cand], scales[cand], row)
            reach = self.near_sigma * np.sqrt(np.maximum(var_z, 0.0))
            crossing_ids = cand[z[cand] - reach <= near]
        n_behind, n_beyond = int(np.count_nonzero(behind)), int(np.count_nonzero(beyond))
        if n_behind or n_beyond or crossing_ids.size:
            keep = ~(behind | beyond)
            keep[crossing_ids] = False
            ids = np.flatnonzero(keep)
            zk = z[ids]
            order = ids[depth_order(zk, self.bits)].astype(np.uint32)
        else:
            zk = z
            order = depth_order(z, self.bits).astype(np.uint32)
        if zk.size:
            dmin, dmax = float(zk.min()), float(zk.max())
        else:
            dmin, dmax = 0.0, 1.0
        return SortResult(order, z, n_behind, int(crossing_ids.size), n_beyond, dmin, dmax)
