"""EWA projection of 3D Gaussians to the image plane (pure torch, differentiable, any float dtype).

This is the projection of 3DGS (Kerbl et al. 2023) in the conventions of ``reconstruct.camera``:
OpenCV camera axes, ``x_cam = R x_world + t``, pixel (row i, column j) centred at (j+0.5, i+0.5).

- ``cov3d = R_q S S^T R_q^T`` with ``R_q`` the rotation of the normalised (w, x, y, z) quaternion and
  ``S = diag(scales)``;
- the 2D covariance is ``J W cov3d W^T J^T + eps2d I`` with W the camera rotation and ``J`` the
  Jacobian of the pinhole projection evaluated at the camera-space mean with ``x/z`` and ``y/z``
  clamped to the view frustum widened by 30 % (3DGS's ``1.3 tan(half fov)`` for a centred
  principal point; the limits are taken per side so that an off-centre principal point behaves
  like gsplat);
- ``conic`` is the inverse 2D covariance stored as (a, b, c) for ``[[a, b], [b, c]]``;
- ``radius = ceil(3 sqrt(largest eigenvalue))`` in pixels; the Gaussian counts at the pixels whose
  centres lie within ``radius`` of the projected mean along both axes (its *box*);
- Gaussians whose depth is not beyond the near plane, or whose box misses the image, get radius 0.

Numerical guards (they change nothing for ordinary Gaussians with eps2d = 0.3; see docs/stability.md):

- quaternions are scaled by their largest component before normalising (no overflow of the norm
  of huge ones in float32), and those below ``MIN_QUAT_NORM`` are taken as the identity;
- the 2D covariance is computed from ``M / s``, ``s`` the largest entry of M (no overflow of its
  squares for huge Gaussians), with the determinant as ``|m_x x m_y|^2 + eps2d (|m_x|^2 + |m_y|^2)
  + eps2d^2`` (Lagrange's identity: a sum of non-negative terms, free of the cancellation of
  ``a c - b^2``, which lost whole Gaussians to a negative determinant in float32);
- its eigenvalues are clamped to [``MIN_EIGENVALUE``, ``MAX_EIGENVALUE``]: the largest by scaling
  the whole covariance down (a Gaussian wider than the largest radius looks the same), the smallest
  by adding a multiple of the identity, so that conics stay finite when eps2d = 0;
- a Gaussian whose screen footprint or position changes with depth faster than
  ``MAX_DEPTH_DERIVATIVE`` (1e30 px/m: a near plane of 1e-30, scales of 1e38), or is not finite, is
  culled with its inputs replaced before use, so that no overflowing derivative and no inf * 0 can
  put an inf or a NaN into a gradient. The limit is the same in float32 and float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

FRUSTUM_MARGIN = 0.3  # the Jacobian is evaluated within the frustum widened by this fraction
MAX_RADIUS = 1 << 20  # pixel radii are clamped here so that integer boxes cannot overflow
MAX_EIGENVALUE = (MAX_RADIUS / 3.0) ** 2  # px^2: a 2D covariance is never wider than the largest radius
MIN_EIGENVALUE = 1e-2  # px^2 (a standard deviation of 0.1 px): keeps conics finite and tame with eps2d = 0
MIN_QUAT_NORM = 1e-12  # quaternions shorter than this (largest component) are the identity
MAX_DEPTH_DERIVATIVE = 1e30  # px/m: Gaussians whose footprint or position changes faster with depth are culled


@dataclass
class Projection:
    """Per-Gaussian screen-space quantities.

    means2d (N,2) pixel coordinates; conics (N,3) inverse 2D covariance (a, b, c); depths (N,)
    camera-space z; radii (N,) int32 pixel radius, 0 = culled; boxes (N,4) int32 inclusive pixel
    ranges (x_lo, x_hi, y_lo, y_hi) clipped to the image, empty (x_lo > x_hi) when culled.
    """

    means2d: Tensor
    conics: Tensor
    depths: Tensor
    radii: Tensor
    boxes: Tensor


def _rotmat_from_products() -> Tensor:
    """(9, 16) matrix B with R(q).flatten() = B @ (q q^T).flatten() for a unit (w, x, y, z) q."""
    B = torch.zeros(9, 4, 4, dtype=torch.float64)
    w, x, y, z = range(4)
    terms = {  # entry of R (row-major) -> [(coefficient, i, j)] over the products q_i q_j
        0: [(1, w, w), (1, x, x), (-1, y, y), (-1, z, z)],
        1: [(2, x, y), (-2, w, z)],
        2: [(2, x, z), (2, w, y)],
        3: [(2, x, y), (2, w, z)],
        4: [(1, w, w), (-1, x, x), (1, y, y), (-1, z, z)],
        5: [(2, y, z), (-2, w, x)],
        6: [(2, x, z), (-2, w, y)],
        7: [(2, y, z), (2, w, x)],
        8: [(1, w, w), (-1, x, x), (-1, y, y), (1, z, z)],
    }
    for entry, products in terms.items():
        for coefficient, i, j in products:
            B[entry, i, j] = coefficient
    return B.reshape(9, 16)


_ROTMAT_FROM_PRODUCTS = _rotmat_from_products()


def rotation_matrices(quats: Tensor) -> Tensor:
    """Rotations of (w, x, y, z) quaternions (N,4) as a (3, 3, N) tensor (entry [i, j, n] = R_n[i, j]).

    Quaternions are normalised here (see ``safe_normalize_quats``). The component-major layout keeps
    every torch op contiguous (batched 3x3 matmuls and strided broadcasts are slow in torch)."""
    q = safe_normalize_quats(quats).T.contiguous()
    products = (q[:, None, :] * q[None, :, :]).reshape(16, -1)
    return (_ROTMAT_FROM_PRODUCTS.to(products) @ products).reshape(3, 3, -1)


def safe_normalize_quats(quats: Tensor) -> Tensor:
    """Unit quaternions (N,4): each one divided by its largest absolute component first (so that
    the norm of a huge one cannot overflow, nor a tiny one's underflow), then by its norm; one
    whose largest component is below ``MIN_QUAT_NORM`` is the identity (1, 0, 0, 0), with a zero
    gradient rather than one of size 1/|q|."""
    big = quats.detach().abs().amax(dim=-1, keepdim=True)
    ok = big > MIN_QUAT_NORM
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=quats.dtype, device=quats.device)
    q = torch.where(ok, quats, identity) / torch.where(ok, big, torch.ones_like(big))
    return torch.where(ok, q / q.norm(dim=-1, keepdim=True), identity)


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices (N,3,3) of (w, x, y, z) quaternions (see ``rotation_matrices``)."""
    return rotation_matrices(quats).permute(2, 0, 1)


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World-space covariances (N,3,3) ``R S S^T R^T``."""
    m = quat_to_rotmat(quats) * scales[:, None, :]
    return m @ m.transpose(-1, -2)


def pixel_boxes(means2d: Tensor, radii: Tensor, width: int, height: int) -> Tensor:
    """Inclusive pixel index ranges (x_lo, x_hi, y_lo, y_hi) of the pixels whose centres lie within
    ``radii`` of ``means2d`` along both axes, clipped to the image; (0, -1, 0, -1) where radius 0.

    This is the one definition of "the pixels a Gaussian touches" shared by every backend."""
    m = means2d.detach()
    r = radii.to(m.dtype)
    lo = torch.ceil(m - r[:, None] - 0.5)
    hi = torch.floor(m + r[:, None] - 0.5)
    size = torch.tensor([width, height], dtype=m.dtype, device=m.device).expand_as(lo)
    lo = torch.minimum(torch.maximum(lo, torch.zeros_like(lo)), size)  # in [0, size]
    hi = torch.maximum(torch.minimum(hi, size - 1), torch.full_like(hi, -1.0))  # in [-1, size-1]
    box = torch.stack([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]], dim=-1).to(torch.int32)
    empty = torch.tensor([0, -1, 0, -1], dtype=torch.int32, device=m.device)
    return torch.where((radii > 0)[:, None], box, empty)


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    R: Tensor,
    t: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    eps2d: float = 0.3,
    near: float = 0.01,
) -> Projection:
    """Project N Gaussians with the camera (R, t, K); see the module docstring for the rules.

    R (3,3), t (3,), K (3,3) must have the dtype and device of ``means``. Differentiable w.r.t.
    means, quats and scales through ``means2d``, ``conics`` and ``depths``; culled Gaussians get
    finite (meaningless) values so that no NaN can reach a gradient. Internally every quantity is
    laid out component-major, (components, N), so that each torch op runs on contiguous rows."""
    x, y, depth = (R @ means.T + t[:, None]).unbind(0)  # unbind: one backward node, no zero fills
    in_front = depth > near
    z = torch.where(in_front, depth, torch.ones_like(depth))  # safe divisor for culled ones
    rot = rotation_matrices(quats)
    m_x, m_y, means2d = _screen_jacobian(x, y, z, rot, scales, R, K, width, height)
    # footprints and positions that change with depth faster than MAX_DEPTH_DERIVATIVE (or are not
    # finite) are culled, with their inputs made harmless: their gradients would overflow float32
    size = _largest_entry(m_x, m_y)
    rate = torch.maximum(size, (means2d.detach() - K[:2, 2]).abs().amax(dim=1)) / z.detach()
    finite = rate <= MAX_DEPTH_DERIVATIVE  # False for NaN too
    if not bool(finite.all()):
        in_front = in_front & finite
        one = torch.ones_like(z)
        x, y, z = (torch.where(finite, v, w) for v, w in ((x, 0 * one), (y, 0 * one), (z, one)))
        m_x, m_y, means2d = _screen_jacobian(x, y, z, rot, torch.where(finite[:, None], scales, 1.0), R, K,
                                             width, height)
        size = _largest_entry(m_x, m_y)

    a, b, c, det, lam_max = _covariance_2d(m_x, m_y, size.clamp_min(1.0), eps2d)
    valid = in_front & (det > 0)
    det = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)

    radii = _radii(lam_max, valid)
    boxes = pixel_boxes(means2d, radii, width, height)
    visible = (boxes[:, 0] <= boxes[:, 1]) & (boxes[:, 2] <= boxes[:, 3])
    radii = torch.where(visible, radii, torch.zeros_like(radii))
    return Projection(means2d, conics, depth, radii, boxes)


def _screen_jacobian(x, y, z, rot, scales, R, K, width, height):
    """Rows m_x, m_y (3, N) of M = J R Rq S (J the projection Jacobian, R the camera rotation, Rq S
    the scaled local axes; one column per local axis) and the projected means (N,2)."""
    axes = (R @ rot.reshape(3, -1)).reshape(3, 3, -1) * scales.T[None]
    axes_x, axes_y, axes_z = axes.unbind(0)  # camera-space x, y, z of the three scaled local axes
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u, v = _clamped_directions(x, y, z, K, width, height)
    m_x = (fx / z) * (axes_x - u * axes_z)
    m_y = (fy / z) * (axes_y - v * axes_z)
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)
    return m_x, m_y, means2d


def _largest_entry(m_x: Tensor, m_y: Tensor) -> Tensor:
    """(N,) largest |entry| of each M (detached)."""
    return torch.maximum(m_x.detach().abs().amax(dim=0), m_y.detach().abs().amax(dim=0))


def _covariance_2d(m_x: Tensor, m_y: Tensor, s: Tensor, eps2d: float):
    """Entries a, b, c of ``cov2d = M M^T + eps2d I`` with its eigenvalues clamped to
    [MIN_EIGENVALUE, MAX_EIGENVALUE], its determinant and its largest eigenvalue (all (N,)).
    ``s`` >= 1 is M's largest entry (detached): s^2 (M/s)(M/s)^T is M M^T exactly, without the
    overflow of squaring huge entries."""
    m_x, m_y = m_x / s, m_y / s
    a0 = (m_x * m_x).sum(dim=0)
    c0 = (m_y * m_y).sum(dim=0)
    b0 = (m_x * m_y).sum(dim=0)
    # |m_x x m_y|^2 = a0 c0 - b0^2 without the cancellation
    cross = torch.stack([m_x[1] * m_y[2] - m_x[2] * m_y[1], m_x[2] * m_y[0] - m_x[0] * m_y[2],
                         m_x[0] * m_y[1] - m_x[1] * m_y[0]])
    cross2 = (cross * cross).sum(dim=0)
    # largest eigenvalue of (M/s)(M/s)^T, detached: it sets radii and clamps only (and the gradient
    # of this sqrt is infinite for isotropic footprints)
    a0d, b0d, c0d = a0.detach(), b0.detach(), c0.detach()
    lam0 = 0.5 * (a0d + c0d) + torch.sqrt(0.25 * (a0d - c0d) ** 2 + b0d * b0d)
    # the largest eigenvalue s^2 lam0 + eps2d is clamped to MAX_EIGENVALUE by using k^2 < s^2 (detached)
    k2 = torch.minimum(s * s, (MAX_EIGENVALUE - eps2d) / lam0.clamp_min(1e-30)).clamp_min(0.0)
    a = k2 * a0 + eps2d
    b = k2 * b0
    c = k2 * c0 + eps2d
    det = (k2 * k2) * cross2 + eps2d * (k2 * (a0 + c0)) + eps2d * eps2d
    lam_max = k2 * lam0 + eps2d
    # the smallest eigenvalue det / lam_max is raised to MIN_EIGENVALUE by adding d I (detached d)
    lam_min = det.detach() / lam_max.clamp_min(1e-30)
    d = (MIN_EIGENVALUE - lam_min).clamp_min(0.0)
    if bool((d > 0).any()):
        det = det + d * (a + c) + d * d
        a, c, lam_max = a + d, c + d, lam_max + d
    return a, b, c, det, lam_max


def _clamped_directions(x: Tensor, y: Tensor, z: Tensor, K: Tensor, width: int, height: int):
    """x/z and y/z clamped to the frustum widened by ``FRUSTUM_MARGIN`` on each side, where the
    Jacobian is evaluated (the clamped entries pass no gradient to the mean, as in 3DGS)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    margin_x = FRUSTUM_MARGIN * 0.5 * width / fx
    margin_y = FRUSTUM_MARGIN * 0.5 * height / fy
    u = torch.clamp(x / z, min=-(cx / fx + margin_x), max=(width - cx) / fx + margin_x)
    v = torch.clamp(y / z, min=-(cy / fy + margin_y), max=(height - cy) / fy + margin_y)
    return u, v


def _radii(lam_max: Tensor, valid: Tensor) -> Tensor:
    """int32 ``ceil(3 sqrt(lambda_max))`` of the 2D covariances, 0 where invalid."""
    r = torch.ceil(3.0 * torch.sqrt(lam_max.clamp_min(0.0))).clamp(max=MAX_RADIUS)
    r = torch.where(valid & torch.isfinite(r), r, torch.zeros_like(r))
    return r.to(torch.int32)
