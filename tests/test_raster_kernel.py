"""The compositing stage: compiled CPU kernel vs the pure-torch reference vs the literal rules.

Agreement figures are printed (run with -s to see them)."""

from __future__ import annotations

import math
import os
import shutil

import numpy as np
import pytest
import torch

from reconstruct.camera import Camera
from reconstruct.gaussians import quats_aligning_z
from reconstruct.raster import cpu_backend, rasterization
from reconstruct.raster.projection import project_gaussians
from reconstruct.raster.reference import rasterize_reference

# with a compiler present the kernel must build: a build error then fails these tests
pytestmark = pytest.mark.skipif(shutil.which(os.environ.get("CXX", "c++")) is None,
                                reason="no C++ compiler to build the CPU rasterizer")

F64 = torch.float64


# ------------------------------------------------------------------------------------------------
# scenes
# ------------------------------------------------------------------------------------------------

def random_scene(n: int, seed: int, channels: int = 3) -> dict:
    """Gaussians scattered in a 1 m cube 3 m in front of the camera of ``camera_for`` (float64)."""
    g = torch.Generator().manual_seed(seed)
    return {
        "means": torch.rand(n, 3, generator=g, dtype=F64) - 0.5,
        "quats": torch.randn(n, 4, generator=g, dtype=F64),
        "scales": torch.rand(n, 3, generator=g, dtype=F64) * 0.06 + 0.01,
        "opacities": torch.rand(n, generator=g, dtype=F64) * 0.9 + 0.05,
        "features": torch.rand(n, channels, generator=g, dtype=F64),
    }


def camera_for(width: int, height: int) -> Camera:
    """Looks at the origin from 3 m along -Y, with an off-centre principal point."""
    cam = Camera.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), width=width, height=height, fov_y_deg=28)
    K = cam.K.copy()
    K[0, 2] += 0.11 * width
    K[1, 2] -= 0.07 * height
    return Camera(K, cam.R, cam.t, width, height)


CAPSULES = [  # (a, b, radius): a ~1.7 m figure, Z up
    ((0, 0, 0.95), (0, 0, 1.40), 0.16), ((0, 0, 1.55), (0, 0, 1.62), 0.10),
    ((-0.1, 0, 0.08), (-0.1, 0, 0.88), 0.07), ((0.1, 0, 0.08), (0.1, 0, 0.88), 0.07),
    ((-0.2, 0, 1.38), (-0.45, 0, 0.85), 0.05), ((0.2, 0, 1.38), (0.45, 0, 0.85), 0.05),
]


def body_scene(n: int, seed: int = 0) -> dict:
    """Gaussians on closed capsule surfaces (front and back surfaces occlude each other), flat
    along the surface normal, sized like their spacing."""
    rng = np.random.default_rng(seed)
    per = n // len(CAPSULES)
    points, normals = [], []
    for a, b, r in CAPSULES:
        a, b = np.asarray(a, float), np.asarray(b, float)
        d = rng.normal(size=(per, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        h = rng.random(per)[:, None]
        axis = (b - a) / np.linalg.norm(b - a)
        radial = d - (d @ axis)[:, None] * axis
        radial /= np.linalg.norm(radial, axis=1, keepdims=True)
        side = rng.random(per) < 0.8
        normal = np.where(side[:, None], radial, d)
        base = np.where(side[:, None], a + h * (b - a), np.where((d @ axis)[:, None] > 0, b, a))
        points.append(base + r * normal)
        normals.append(normal)
    points, normals = np.concatenate(points), np.concatenate(normals)
    m = len(points)
    spacing = math.sqrt(2.0 / m)
    quats = quats_aligning_z(normals)
    scales = np.array([1.0, 1.0, 0.3]) * spacing * rng.uniform(0.7, 1.3, size=(m, 1))
    t = lambda a: torch.tensor(a, dtype=F64)  # noqa: E731
    return {"means": t(points), "quats": t(quats), "scales": t(scales),
            "opacities": t(rng.uniform(0.5, 1.0, m)), "features": t(rng.random((m, 3)))}


def body_camera(size: int) -> Camera:
    return Camera.look_at((0.3, -3.0, 1.0), (0.0, 0.0, 0.85), width=size, height=size, fov_y_deg=36)


def stage_inputs(scene: dict, cam: Camera, seed: int = 0):
    """Projected (float64) inputs of the compositing stage: the scene features plus a depth channel."""
    R, t, K = (torch.tensor(a, dtype=F64) for a in (cam.R, cam.t, cam.K))
    p = project_gaussians(scene["means"], scene["quats"], scene["scales"], R, t, K, cam.width, cam.height)
    g = torch.Generator().manual_seed(seed)
    background = torch.rand(scene["features"].shape[1] + 1, generator=g, dtype=F64)
    features = torch.cat([scene["features"], p.depths[:, None]], dim=1)
    tensors = [p.means2d, p.conics, scene["opacities"], features, background]
    return [x.detach() for x in tensors], p.depths.detach(), p.boxes


def composite(fn, tensors, depths, boxes, width, height, *, seed=1, hit_threshold=0.5, **kwargs):
    """Run a compositor and backpropagate a random linear loss of image and alpha."""
    leaves = [x.clone().requires_grad_() for x in tensors]
    image, alpha, first_hit = fn(*leaves, depths, boxes, width, height, return_first_hit=True,
                                 hit_threshold=hit_threshold, **kwargs)
    g = torch.Generator().manual_seed(seed)
    w_image = torch.rand(image.shape, generator=g, dtype=F64).to(image.dtype)
    w_alpha = torch.rand(alpha.shape, generator=g, dtype=F64).to(alpha.dtype)
    ((image * w_image).sum() + (alpha * w_alpha).sum()).backward()
    return image.detach(), alpha.detach(), first_hit, [x.grad for x in leaves]


def rel_err(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a.double() - b.double()).abs().max() / b.double().abs().max().clamp_min(1e-30))


# ------------------------------------------------------------------------------------------------
# the literal rules, one pixel at a time (tests the reference itself)
# ------------------------------------------------------------------------------------------------

def literal_composite(means2d, conics, opacities, features, background, depths, boxes, width, height,
                      hit_threshold):
    order = sorted(range(len(depths)), key=lambda g: (float(depths[g]), g))
    image = np.zeros((height, width, features.shape[1]))
    alpha_out = np.zeros((height, width))
    first_hit = np.full((height, width), -1)
    for i in range(height):
        for j in range(width):
            T, color, weight, hit = 1.0, np.zeros(features.shape[1]), 0.0, -1
            for g in order:
                x_lo, x_hi, y_lo, y_hi = (int(v) for v in boxes[g])
                if not (x_lo <= j <= x_hi and y_lo <= i <= y_hi):
                    continue
                dx, dy = j + 0.5 - float(means2d[g, 0]), i + 0.5 - float(means2d[g, 1])
                a, b, c = (float(v) for v in conics[g])
                alpha = min(0.99, float(opacities[g]) * math.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)))
                if alpha < 1.0 / 255.0:
                    continue
                if T * (1.0 - alpha) < 1e-4:
                    break
                color += features[g].numpy() * alpha * T
                weight += alpha * T
                T *= 1.0 - alpha
                if hit < 0 and 1.0 - T >= hit_threshold:
                    hit = g
            image[i, j] = color + T * background.numpy()
            alpha_out[i, j] = weight
            first_hit[i, j] = hit
    return image, alpha_out, first_hit


def opaque_stack(n_opaque: int, n_faint: int, width: int, height: int, channels: int = 2):
    """Gaussians centred near pixel (row 5, col 6) at increasing depth 1, 2, ...: opaque ones
    (alpha ~0.9-0.95 at that pixel), then faint ones (alpha 0.05) that a pixel must not pick up
    after it stopped. Their boxes cover the whole image."""
    n = n_opaque + n_faint
    means2d = torch.tensor([[6.5 + 0.3 * (k % 3), 5.5 - 0.2 * (k % 2)] for k in range(n)], dtype=F64)
    conics = torch.tensor([[0.3, 0.05 * (k % 2), 0.25] for k in range(n)], dtype=F64)
    opacities = torch.tensor([0.95] * n_opaque + [0.05] * n_faint, dtype=F64)
    features = torch.rand(n, channels, generator=torch.Generator().manual_seed(3), dtype=F64)
    background = torch.linspace(0.2, 0.7, channels, dtype=F64)
    depths = torch.arange(1, n + 1, dtype=F64)
    boxes = torch.tensor([[0, width - 1, 0, height - 1]] * n, dtype=torch.int32)
    return [means2d, conics, opacities, features, background], depths, boxes


# ------------------------------------------------------------------------------------------------
# tests
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("layers", [1, 2, 3, 32])
def test_reference_follows_the_literal_rules(layers):
    """Random Gaussians behind an opaque stack (so that some pixels terminate), for several chunk
    sizes of the reference."""
    width, height = 24, 18
    tensors, depths, boxes = stage_inputs(random_scene(25, seed=4), camera_for(width, height))
    stack, stack_depths, stack_boxes = opaque_stack(5, 4, width, height, channels=tensors[3].shape[1])
    tensors = [torch.cat([a, b]) for a, b in zip(tensors[:4], stack[:4])] + [tensors[4]]
    depths = torch.cat([depths, stack_depths * 0.01])
    boxes = torch.cat([boxes, stack_boxes])
    image, alpha, hit = rasterize_reference(*tensors, depths, boxes, width, height, return_first_hit=True,
                                            hit_threshold=0.4, layers=layers)
    want_image, want_alpha, want_hit = literal_composite(*tensors, depths, boxes, width, height, 0.4)
    assert np.abs(image.numpy() - want_image).max() < 1e-12
    assert np.abs(alpha.numpy() - want_alpha).max() < 1e-12
    assert (hit.numpy() == want_hit).all()
    assert (alpha.numpy() > 0.999).any(), "the scene must contain terminated pixels"


@pytest.mark.parametrize("fn", [cpu_backend.rasterize_cpu, rasterize_reference], ids=["kernel", "reference"])
def test_early_termination_in_an_opaque_stack(fn):
    """Three opaque Gaussians leave T ~ 3e-4 at pixel (5, 6); the fourth would take it below 1e-4,
    so the pixel stops there and never picks up the faint ones behind (whose T * (1 - alpha) would
    still be above 1e-4), whatever the chunking of the reference."""
    width, height = 12, 10
    tensors, depths, boxes = opaque_stack(6, 5, width, height)
    kwargs = {"layers": 4} if fn is rasterize_reference else {}
    image, alpha, _, _ = composite(fn, tensors, depths, boxes, width, height, **kwargs)
    means2d, conics, opacities, features, background = tensors
    T, want = 1.0, torch.zeros(2, dtype=F64)
    for k in range(3):
        dx, dy = (torch.tensor([6.5, 5.5], dtype=F64) - means2d[k]).tolist()
        a, b, c = conics[k].tolist()
        alpha_k = min(0.99, 0.95 * math.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)))
        want += features[k] * alpha_k * T
        T *= 1 - alpha_k
    assert 1e-4 < T < 4e-4
    want += T * background
    assert torch.allclose(image[5, 6], want, atol=1e-12)
    assert abs(float(alpha[5, 6]) - (1 - T)) < 1e-12
    # nothing behind the third Gaussian reaches that pixel: changing their features is invisible
    changed = [x.clone() for x in tensors]
    changed[3][3:] += 10.0
    image2, *_ = composite(fn, changed, depths, boxes, width, height, **kwargs)
    assert torch.equal(image2[5, 6], image[5, 6])
    assert not torch.equal(image2, image)


def test_equal_depths_are_taken_in_index_order():
    width, height = 12, 10
    tensors, depths, boxes = opaque_stack(3, 3, width, height)
    tensors[2] = torch.tensor([0.45, 0.9, 0.3, 0.7, 0.6, 0.8], dtype=F64)
    depths = torch.full((6,), 2.0, dtype=F64)
    want_image, _, want_hit = literal_composite(*tensors, depths, boxes, width, height, 0.5)
    for fn in (cpu_backend.rasterize_cpu, rasterize_reference):
        image, _, hit = fn(*tensors, depths, boxes, width, height, return_first_hit=True)
        assert np.abs(image.numpy() - want_image).max() < 1e-12
        assert (hit.numpy() == want_hit).all()
    assert want_hit[5, 6] == 1  # Gaussian 0 (alpha 0.45) is below the threshold, 1 comes next


def assert_kernel_matches_reference_float64(scene, cam, label):
    """Float64 compiled kernel against the float64 reference: images, alpha and every gradient to
    1e-10, identical first-hit ids; returns the reference's (image, alpha, first_hit, grads)."""
    tensors, depths, boxes = stage_inputs(scene, cam)
    k = composite(cpu_backend.rasterize_cpu, tensors, depths, boxes, cam.width, cam.height)
    r = composite(rasterize_reference, tensors, depths, boxes, cam.width, cam.height)
    errors = {"image": float((k[0] - r[0]).abs().max()), "alpha": float((k[1] - r[1]).abs().max())}
    errors |= {f"grad {n}": rel_err(a, b) for n, a, b in zip(["means2d", "conics", "opac", "feat", "bg"], k[3], r[3])}
    print(f"float64 kernel vs reference, {label}:", {n: f"{e:.1e}" for n, e in errors.items()})
    assert all(e < 1e-10 for e in errors.values()), errors
    assert torch.equal(k[2], r[2])
    return r


def test_kernel_matches_reference_float64_random():
    r = assert_kernel_matches_reference_float64(random_scene(120, seed=1), camera_for(40, 32), "random scene")
    assert (r[2] >= 0).sum() > 50


def test_kernel_matches_reference_float64_body():
    r = assert_kernel_matches_reference_float64(body_scene(2400), body_camera(80), "body scene")
    assert (r[1] > 0.999).sum() > 100, "the body must occlude itself"


def test_kernel_float32_matches_float64_reference_body():
    """Same depth order for both (the float32 depths, ties broken by index), so only float32
    rounding separates them."""
    cam = body_camera(80)
    tensors, depths, boxes = stage_inputs(body_scene(2400), cam)
    depths32 = depths.float()
    k = composite(cpu_backend.rasterize_cpu, [x.float() for x in tensors], depths32, boxes, cam.width, cam.height)
    r = composite(rasterize_reference, tensors, depths32.double(), boxes, cam.width, cam.height)
    image_err = float((k[0].double() - r[0]).abs().max())
    grad_errs = [rel_err(a, b) for a, b in zip(k[3], r[3])]
    print(f"float32 kernel vs float64 reference, body scene: image {image_err:.1e}, "
          f"gradients (rel.) {max(grad_errs):.1e}, first-hit mismatches {int((k[2] != r[2]).sum())}")
    assert image_err < 1e-4
    assert max(grad_errs) < 1e-4
    assert int((k[2] != r[2]).sum()) <= 2


def test_end_to_end_float32_vs_float64():
    """The whole pipeline (projection included) in float32 against float64; depths are well apart."""
    cam = camera_for(48, 40)
    scene = random_scene(150, seed=5)
    out64 = rasterization(*scene.values(), cam, backend="torch", return_first_hit=True)
    out32 = rasterization(*(v.float() for v in scene.values()), cam, backend="cpu", return_first_hit=True)
    err = {n: float((getattr(out32, n).double() - getattr(out64, n)).abs().max()) for n in ("image", "alpha")}
    covered = out64.alpha > 0.05
    err["depth"] = float((out32.depth.double() - out64.depth)[covered].abs().max())
    print("float32 pipeline vs float64:", {n: f"{e:.1e}" for n, e in err.items()})
    assert err["image"] < 1e-4 and err["alpha"] < 1e-4 and err["depth"] < 1e-4
    assert int((out32.first_hit != out64.first_hit).sum()) == 0


@pytest.mark.parametrize("fn", [cpu_backend.rasterize_cpu, rasterize_reference], ids=["kernel", "reference"])
def test_stage_gradcheck(fn):
    cam = camera_for(24, 20)
    tensors, depths, boxes = stage_inputs(random_scene(12, seed=7), cam)

    def run(*leaves):
        image, alpha, _ = fn(*leaves, depths, boxes, cam.width, cam.height)
        return image, alpha

    leaves = [x.clone().requires_grad_() for x in tensors]
    assert torch.autograd.gradcheck(run, leaves, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def finite_difference_errors(backend: str, scene: dict, cam: Camera, eps: float = 1e-6) -> dict:
    """Max relative error of analytic vs central finite-difference gradients of a random loss of
    image, alpha and depth, per input of ``rasterization``."""
    g = torch.Generator().manual_seed(11)
    background = torch.rand(scene["features"].shape[1], generator=g, dtype=F64)
    inputs = dict(scene, background=background)
    weights = None

    def loss(values: dict) -> torch.Tensor:
        nonlocal weights
        out = rasterization(values["means"], values["quats"], values["scales"], values["opacities"],
                            values["features"], cam, background=values["background"], backend=backend)
        if weights is None:
            weights = [torch.rand(t.shape, generator=g, dtype=F64) for t in (out.image, out.alpha, out.depth)]
        return (out.image * weights[0]).sum() + (out.alpha * weights[1]).sum() + (out.depth * weights[2]).sum()

    leaves = {k: v.clone().requires_grad_() for k, v in inputs.items()}
    loss(leaves).backward()
    errors = {}
    for name, value in inputs.items():
        numeric = torch.zeros_like(value)
        for i in range(value.numel()):
            plus, minus = dict(inputs), dict(inputs)
            plus[name] = value.clone().reshape(-1)
            plus[name][i] += eps
            plus[name] = plus[name].reshape(value.shape)
            minus[name] = value.clone().reshape(-1)
            minus[name][i] -= eps
            minus[name] = minus[name].reshape(value.shape)
            numeric.view(-1)[i] = (loss(plus) - loss(minus)) / (2 * eps)
        errors[name] = rel_err(leaves[name].grad, numeric)
    return errors


@pytest.mark.parametrize("backend", ["cpu", "torch"])
def test_pipeline_gradients_match_finite_differences(backend):
    cam = camera_for(24, 20)
    scene = random_scene(8, seed=3)
    scene["opacities"][0] = 0.999  # one clamped (alpha 0.99) centre
    errors = finite_difference_errors(backend, scene, cam)
    print(f"{backend}: max relative gradient error vs finite differences:",
          {n: f"{e:.1e}" for n, e in errors.items()})
    assert max(errors.values()) < 1e-5, errors


def test_thread_count_does_not_change_results():
    cam = body_camera(96)
    tensors, depths, boxes = stage_inputs(body_scene(3000), cam)
    tensors = [x.float() for x in tensors]
    before = torch.get_num_threads()
    try:
        results = []
        for threads in (1, 2):
            torch.set_num_threads(threads)
            results.append(composite(cpu_backend.rasterize_cpu, tensors, depths.float(), boxes, cam.width, cam.height))
    finally:
        torch.set_num_threads(before)
    (i1, a1, h1, g1), (i2, a2, h2, g2) = results
    assert torch.equal(i1, i2) and torch.equal(a1, a2) and torch.equal(h1, h2)
    assert all(torch.equal(x, y) for x, y in zip(g1, g2))


def test_binning_lists_are_depth_sorted_and_complete():
    cam = camera_for(70, 50)
    _, depths, boxes = stage_inputs(random_scene(200, seed=9), cam)
    ext = cpu_backend.load_extension()
    tile_offsets, ids, slots, gaussian_offsets = ext.bin_gaussians(boxes, depths, cam.width, cam.height)
    tiles_x = math.ceil(cam.width / 16)
    for tile in range(len(tile_offsets) - 1):
        tx, ty = tile % tiles_x, tile // tiles_x
        listed = ids[tile_offsets[tile]:tile_offsets[tile + 1]].tolist()
        want = [g for g in range(len(boxes)) if boxes[g, 0] <= boxes[g, 1]
                and boxes[g, 0] <= 16 * tx + 15 and boxes[g, 1] >= 16 * tx
                and boxes[g, 2] <= 16 * ty + 15 and boxes[g, 3] >= 16 * ty]
        assert listed == sorted(want, key=lambda g: (float(depths[g]), g))
    # every gradient slot is used exactly once, inside its Gaussian's range
    assert sorted(slots.tolist()) == list(range(len(slots)))
    owner = torch.repeat_interleave(torch.arange(len(boxes)), gaussian_offsets.diff())
    assert torch.equal(owner[slots], ids.long())
