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
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

FRUSTUM_MARGIN = 0.3  # the Jacobian is evaluated within the frustum widened by this fraction
MAX_RADIUS = 1 << 20  # pixel radii are clamped here so that integer boxes cannot overflow


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

    Quaternions are normalised here; a zero quaternion is taken as the identity rather than
    divided by zero. The component-major layout keeps every torch op contiguous (batched 3x3 matmuls
    and strided broadcasts are slow in torch)."""
    norm = quats.norm(dim=-1, keepdim=True)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=quats.dtype, device=quats.device)
    q = torch.where(norm > 1e-12, quats / norm.clamp_min(1e-12), identity).T.contiguous()
    products = (q[:, None, :] * q[None, :, :]).reshape(16, -1)
    return (_ROTMAT_FROM_PRODUCTS.to(products) @ products).reshape(3, 3, -1)


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

    # M = J R Rq S (2x3 per Gaussian): J the projection Jacobian, R the camera rotation, Rq S the
    # scaled local axes; cov2d = M M^T + eps2d I
    axes = (R @ rotation_matrices(quats).reshape(3, -1)).reshape(3, 3, -1) * scales.T[None]
    axes_x, axes_y, axes_z = axes.unbind(0)  # camera-space x, y, z of the three scaled local axes
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u, v = _clamped_directions(x, y, z, K, width, height)
    m_x = (fx / z) * (axes_x - u * axes_z)  # (3, N): row x of M, one column per local axis
    m_y = (fy / z) * (axes_y - v * axes_z)
    a = (m_x * m_x).sum(dim=0) + eps2d
    b = (m_x * m_y).sum(dim=0)
    c = (m_y * m_y).sum(dim=0) + eps2d
    det = a * c - b * b
    valid = in_front & (det > 0)
    det = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)

    radii = _radii(a.detach(), b.detach(), c.detach(), valid)
    boxes = pixel_boxes(means2d, radii, width, height)
    visible = (boxes[:, 0] <= boxes[:, 1]) & (boxes[:, 2] <= boxes[:, 3])
    radii = torch.where(visible, radii, torch.zeros_like(radii))
    return Projection(means2d, conics, depth, radii, boxes)


def _clamped_directions(x: Tensor, y: Tensor, z: Tensor, K: Tensor, width: int, height: int):
    """x/z and y/z clamped to the frustum widened by ``FRUSTUM_MARGIN`` on each side, where the
    Jacobian is evaluated (the clamped entries pass no gradient to the mean, as in 3DGS)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    margin_x = FRUSTUM_MARGIN * 0.5 * width / fx
    margin_y = FRUSTUM_MARGIN * 0.5 * height / fy
    u = torch.clamp(x / z, min=-(cx / fx + margin_x), max=(width - cx) / fx + margin_x)
    v = torch.clamp(y / z, min=-(cy / fy + margin_y), max=(height - cy) / fy + margin_y)
    return u, v


def _radii(a: Tensor, b: Tensor, c: Tensor, valid: Tensor) -> Tensor:
    """int32 ``ceil(3 sqrt(lambda_max))`` of the 2D covariances [[a, b], [b, c]], 0 where invalid."""
    mid = 0.5 * (a + c)
    lam = mid + torch.sqrt(torch.clamp(mid * mid - (a * c - b * b), min=0.0))
    r = torch.ceil(3.0 * torch.sqrt(lam.clamp_min(0.0))).clamp(max=MAX_RADIUS)
    r = torch.where(valid & torch.isfinite(r), r, torch.zeros_like(r))
    return r.to(torch.int32)
