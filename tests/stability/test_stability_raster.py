"""Degenerate Gaussians through the rasterizer (projection + compiled kernel / torch reference).

Each case renders a few Gaussians in float32 with the compiled CPU kernel ("cpu") and with the torch
reference ("torch"), and in float64 with the reference (the oracle), and backpropagates a fixed
weighted mean of image, alpha and depth. Expectation, unless a case says otherwise:
  * outputs and gradients finite;
  * max |gradient| <= GRAD_BOUND (for a loss that is a mean over pixels);
  * float32 image and alpha within F32_TOL (absolute, values in [0, 1]) of float64.
"""

from __future__ import annotations

import pytest
import torch
from stability_helpers import all_finite, record

from reconstruct.camera import Camera
from reconstruct.raster import rasterization
from reconstruct.raster.projection import (
    MAX_EIGENVALUE,
    MAX_RADIUS,
    MIN_EIGENVALUE,
    project_gaussians,
    safe_normalize_quats,
)

GRAD_BOUND = 1e3
F32_TOL = 2e-4
SIZE = 48
BACKENDS = ["cpu", "torch"]


def camera(**kw) -> Camera:
    return Camera.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_y_deg=40, **kw)


def gaussians(n: int = 6, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * 0.6
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = torch.tensor([0.12, 0.04, 0.02], dtype=torch.float64).repeat(n, 1)  # anisotropic
    opacities = torch.full((n,), 0.7, dtype=torch.float64)
    features = torch.rand(n, 3, generator=g, dtype=torch.float64)
    return means, quats, scales, opacities, features


def render(inputs, cam, dtype, backend, **kw):
    """Outputs and gradients of loss = mean(w * image) + mean(alpha) + 0.1 mean(depth)."""
    leaves = [t.to(dtype).clone().requires_grad_(True) for t in inputs]
    out = rasterization(*leaves, cam, backend=backend, **kw)
    w = torch.linspace(0.5, 1.5, out.image.numel(), dtype=dtype).reshape(out.image.shape)
    loss = (w * out.image).mean() + out.alpha.mean() + 0.1 * out.depth.mean()
    loss.backward()
    return out, [t.grad for t in leaves], loss


def check_case(name, inputs, cam, *, grad_bound=GRAD_BOUND, f32_tol=F32_TOL, quat_norm=1.0, **kw):
    """Runs the case and checks the expectations of the module docstring. The gradient of the
    quaternions is measured as |q| * |grad| (it scales as 1/|q|), unless |q| < 1e-12 (identity)."""
    quat_factor = quat_norm if quat_norm >= 1e-12 else 1.0
    ref, ref_grads, _ = render(inputs, cam, torch.float64, "torch", **kw)
    assert all_finite([ref.image, ref.alpha, ref.depth, *ref_grads]), f"{name}: float64 not finite"
    figures = {}
    for backend in BACKENDS:
        out, grads, loss = render(inputs, cam, torch.float32, backend, **kw)
        assert all_finite([out.image, out.alpha, out.depth, loss]), f"{name} ({backend}): non-finite output"
        assert all_finite(grads), f"{name} ({backend}): non-finite gradient"
        gmax = max(float(g.abs().max()) * (quat_factor if i == 1 else 1.0) for i, g in enumerate(grads))
        assert gmax <= grad_bound, f"{name} ({backend}): max |grad| {gmax:.3g} > {grad_bound:g}"
        err = max(float((out.image.detach().double() - ref.image.detach()).abs().max()),
                  float((out.alpha.detach().double() - ref.alpha.detach()).abs().max()))
        assert err <= f32_tol, f"{name} ({backend}): float32 vs float64 error {err:.3g} > {f32_tol:g}"
        figures[f"max_grad_{backend}"] = gmax
        figures[f"f32_err_{backend}"] = err
    figures["coverage"] = float(ref.alpha.detach().mean())
    record(name, **figures)
    return ref


def with_scales(value, n=6):
    m, q, s, o, f = gaussians(n)
    return m, q, torch.as_tensor(value, dtype=torch.float64).expand_as(s).clone(), o, f


def test_vanishing_scales_render_a_dot():
    """scales 1e-30: the eps2d low-pass alone is left (a 0.55 px footprint)."""
    ref = check_case("scales 1e-30 (eps2d 0.3)", with_scales(1e-30), camera())
    assert float(ref.alpha.detach().sum()) > 0


def test_vanishing_scales_without_low_pass_hit_the_eigenvalue_floor():
    """eps2d = 0 and scales 1e-30: the 2D covariance is singular; its eigenvalues are raised to
    MIN_EIGENVALUE, so the conic stays finite (<= 100) instead of dividing by a zero determinant."""
    m, q, s, _, _ = with_scales(1e-30)
    cam = camera()
    R, t, K = (torch.tensor(a) for a in (cam.R, cam.t, cam.K))
    p = project_gaussians(m, q, s, R, t, K, SIZE, SIZE, eps2d=0.0)
    assert torch.isfinite(p.conics).all() and (p.radii > 0).all()
    assert float(p.conics[:, [0, 2]].max()) <= 1.0 / MIN_EIGENVALUE * (1 + 1e-9)
    check_case("scales 1e-30, eps2d 0", with_scales(1e-30), cam, eps2d=0.0)


def test_needles_without_low_pass():
    """Two of three scales 1e-20, eps2d = 0: a rank-1 2D covariance (a line). Before the fix float32
    and float64 disagreed on which of them were culled (a ~ c ~ 1e4, det = a c - b^2 rounded)."""
    check_case("needle (1, 1e-20, 1e-20), eps2d 0", with_scales([1.0, 1e-20, 1e-20]), camera(), eps2d=0.0,
               f32_tol=2e-3)


@pytest.mark.parametrize("length", [30.0, 1e3, 1e4])
def test_long_needles_float32_determinant(length):
    """A needle (length x 1 mm x 1 mm) across the image: the determinant a c - b^2 cancelled in
    float32 (before the fix: float32 vs float64 error 0.0032 at 30 m, 0.60 at 1 km, and the 10 km
    needle culled outright); now computed as a sum of non-negative terms."""
    check_case(f"needle ({length:g}, 1e-3, 1e-3)", with_scales([length, 1e-3, 1e-3]), camera())


@pytest.mark.parametrize("scale", [1e4, 1e10, 1e20, 1e30])
def test_huge_scales(scale):
    """A Gaussian far wider than the image covers it with alpha ~ opacity, in float32 as in float64
    (its 2D covariance is scaled down to MAX_EIGENVALUE). Before the fix, float32 culled it from
    1e10 on (the covariance overflowed) and gave NaN gradients from 1e20 on. From ~1e29 m on, its
    footprint changes with depth faster than MAX_DEPTH_DERIVATIVE: culled in both precisions."""
    ref = check_case(f"scales {scale:g}", with_scales(scale), camera())
    if scale < 1e29:
        assert float(ref.alpha.detach().mean()) > 0.5
    else:
        assert float(ref.alpha.detach().sum()) == 0.0


def test_eigenvalues_are_clamped():
    cam = camera()
    R, t, K = (torch.tensor(a) for a in (cam.R, cam.t, cam.K))
    m, q, s, _, _ = with_scales(1e20)
    p = project_gaussians(m, q, s, R, t, K, SIZE, SIZE)
    assert (p.radii == MAX_RADIUS).all()
    a, b, c = p.conics.unbind(-1)
    lam_min_conic = 0.5 * (a + c) - torch.sqrt(0.25 * (a - c) ** 2 + b * b)  # 1 / largest covariance eigenvalue
    assert (lam_min_conic >= 1.0 / MAX_EIGENVALUE * (1 - 1e-6)).all()


@pytest.mark.parametrize("norm", [0.0, 1e-20, 1e-6, 1e30])
def test_quaternion_norms(norm):
    """Quaternions of norm 0 and 1e-20 are the identity (zero gradient); 1e-6 and 1e30 are the
    same rotation as the unit one. The gradient of a quaternion is that of its rotation divided by
    |q|, so the bound is on |q| * max |grad|."""
    m, q, s, o, f = gaussians()
    unit = safe_normalize_quats(q)
    small = (unit * norm).requires_grad_(True)
    n = safe_normalize_quats(small)
    expected = unit if norm >= 1e-12 else torch.tensor([1.0, 0, 0, 0], dtype=torch.float64).expand_as(unit)
    assert torch.allclose(n, expected, atol=1e-12)
    n32 = safe_normalize_quats((unit * norm).float())
    assert torch.allclose(n32.double(), expected, atol=1e-6)
    inputs = (m, unit * norm, s, o, f)
    check_case(f"quaternions of norm {norm:g}", inputs, camera(), quat_norm=norm)
    _, grads, _ = render(inputs, camera(), torch.float32, "cpu")
    if norm < 1e-12:
        assert float(grads[1].abs().max()) == 0.0


@pytest.mark.parametrize("where", ["on the near plane", "behind the camera", "just beyond the near plane",
                                   "near plane 1e-30", "near plane 1e-37 (float32 overflow)"])
def test_points_at_the_near_plane(where):
    """Three of six Gaussians at a depth about the near plane, near the optical axis (the camera sits
    at the origin, so that depths of 1e-37 are represented exactly). At 1e-37 the Jacobian f/z
    overflows float32: those Gaussians are culled with zero gradients instead of NaN ones."""
    m, q, s, o, f = gaussians()
    cam = Camera.look_at((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), width=SIZE, height=SIZE, fov_y_deg=40)
    kw = {}
    depth = {"on the near plane": 0.01, "behind the camera": -1.0, "just beyond the near plane": 0.0105,
             "near plane 1e-30": 2e-30, "near plane 1e-37 (float32 overflow)": 2e-37}[where]
    if "1e-3" in where:
        kw["near"] = depth / 2
    m = m.clone()
    m[:, 1] += 3.0  # the others at depth ~3
    m[:3, 1] = depth
    m[:3, [0, 2]] *= abs(depth)  # near the optical axis
    check_case(f"points {where}", (m, q, s, o, f), cam, **kw)


def test_all_gaussians_in_one_pixel():
    """3000 Gaussians on one point: per-pixel lists 3000 long; early termination; the compiled
    backward recovers each transmittance by dividing by (1 - alpha) hundreds of times."""
    n = 3000
    g = torch.Generator().manual_seed(1)
    means = torch.zeros(n, 3, dtype=torch.float64)
    means[:, 1] = torch.rand(n, generator=g, dtype=torch.float64) * 1e-3  # distinct depths
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = torch.full((n, 3), 1e-4, dtype=torch.float64)
    opacities = torch.full((n,), 0.02, dtype=torch.float64)
    features = torch.rand(n, 3, generator=g, dtype=torch.float64)
    inputs = (means, quats, scales, opacities, features)
    check_case("3000 Gaussians in one pixel", inputs, camera())
    _, ref_grads, _ = render(inputs, camera(), torch.float64, "torch")
    _, grads, _ = render(inputs, camera(), torch.float32, "cpu")
    # means, opacities, features (the scales are isotropic: the quaternions' gradient is 0 up to rounding)
    rel = max(float((grads[i].double() - ref_grads[i]).norm() / ref_grads[i].norm()) for i in (0, 3, 4))
    record("3000 Gaussians in one pixel: gradient f32 vs f64", rel_grad_err=rel)
    # all ~450 Gaussians before the T < 1e-4 cut have the same alpha: rounding moves the cut by one
    # Gaussian in float32, a discrete change of ~1/450 of the gradient (the same for both backends)
    assert rel < 1e-2


def test_a_view_with_everything_culled_still_backpropagates():
    """Bug found: with every Gaussian culled the torch reference returned outputs without a
    grad_fn, so ``loss.backward()`` of a training step raised; now zero gradients, as the kernel."""
    m, q, s, o, f = gaussians()
    m = m.clone()
    m[:, 1] = -10.0  # all behind the camera
    for backend in BACKENDS:
        _, grads, _ = render((m, q, s, o, f), camera(), torch.float32, backend)
        assert all(float(g.abs().max()) == 0 for g in grads)
