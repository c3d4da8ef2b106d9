"""The public entry point: outputs, depth and first-hit semantics, bad input, backends."""

from __future__ import annotations

import os
import re
import shutil
import warnings

import pytest
import torch

from reconstruct.camera import Camera
from reconstruct.raster import RasterOutput, available_backends, cpu_backend, rasterization
from reconstruct.raster import rasterize as rasterize_module

F64 = torch.float64
# with a compiler present the CPU kernel must build (a build error then fails the "cpu" cases)
LOCAL_BACKENDS = ["cpu", "torch"] if shutil.which(os.environ.get("CXX", "c++")) else ["torch"]


def front_camera(width: int = 32, height: int = 24) -> Camera:
    """Looks along +Y from (0, -3, 0): world x maps to image columns, world -z to image rows."""
    return Camera.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), width=width, height=height, fov_y_deg=30)


def random_gaussians(n: int, channels: int = 3, seed: int = 0, dtype=F64) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {
        "means": ((torch.rand(n, 3, generator=g, dtype=F64) - 0.5) * 1.2).to(dtype),
        "quats": torch.randn(n, 4, generator=g, dtype=F64).to(dtype),
        "scales": (torch.rand(n, 3, generator=g, dtype=F64) * 0.05 + 0.01).to(dtype),
        "opacities": (torch.rand(n, generator=g, dtype=F64) * 0.9 + 0.05).to(dtype),
        "features": torch.rand(n, channels, generator=g, dtype=F64).to(dtype),
    }


def splats(positions, scales, opacities, features) -> dict:
    """Axis-aligned Gaussians from lists."""
    n = len(positions)
    return {"means": torch.tensor(positions, dtype=F64), "quats": torch.tensor([[1.0, 0, 0, 0]] * n, dtype=F64),
            "scales": torch.tensor(scales, dtype=F64), "opacities": torch.tensor(opacities, dtype=F64),
            "features": torch.tensor(features, dtype=F64)}


# ------------------------------------------------------------------------------------------------
# outputs
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", LOCAL_BACKENDS)
@pytest.mark.parametrize("channels", [1, 3, 7])
def test_output_shapes_and_gradients(backend, channels):
    cam = front_camera(30, 20)
    inputs = {k: v.requires_grad_() for k, v in random_gaussians(40, channels).items()}
    background = torch.rand(channels, dtype=F64, requires_grad=True)
    out = rasterization(*inputs.values(), cam, background=background, backend=backend, return_first_hit=True)
    assert isinstance(out, RasterOutput)
    assert out.image.shape == (20, 30, channels) and out.image.dtype == F64
    assert out.alpha.shape == out.depth.shape == out.first_hit.shape == (20, 30)
    assert out.first_hit.dtype == torch.int64 and out.radii.shape == (40,)
    (out.image.sum() + out.alpha.sum() + out.depth.sum()).backward()
    for name, tensor in list(inputs.items()) + [("background", background)]:
        assert tensor.grad is not None and torch.isfinite(tensor.grad).all(), name
        assert tensor.grad.abs().sum() > 0, name


@pytest.mark.parametrize("backend", LOCAL_BACKENDS)
def test_no_gaussians_gives_the_background(backend):
    background = torch.tensor([0.1, 0.5, 0.9], dtype=F64, requires_grad=True)
    empty = {k: v[:0] for k, v in random_gaussians(3).items()}
    out = rasterization(*empty.values(), front_camera(), background=background, backend=backend,
                        return_first_hit=True)
    assert torch.equal(out.image, background.detach().expand(24, 32, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all() and (out.first_hit == -1).all()
    assert out.radii.shape == (0,)
    out.image.sum().backward()
    assert torch.equal(background.grad, torch.full((3,), 24.0 * 32, dtype=F64))


@pytest.mark.parametrize("backend", LOCAL_BACKENDS)
def test_all_gaussians_culled_gives_the_background(backend):
    scene = random_gaussians(10)
    scene["means"][:, 1] = -5.0  # all behind the camera at y = -3
    background = torch.tensor([0.3, 0.2, 0.1], dtype=F64)
    out = rasterization(*scene.values(), front_camera(), background=background, backend=backend,
                        return_first_hit=True)
    assert (out.radii == 0).all()
    assert torch.equal(out.image, background.expand(24, 32, 3)) and (out.first_hit == -1).all()


@pytest.mark.parametrize("backend", LOCAL_BACKENDS)
def test_default_background_is_zero_and_empty_pixels_have_zero_depth(backend):
    scene = splats([[0.0, 0.0, 0.0]], [[0.02, 0.02, 0.02]], [0.8], [[1.0, 1.0]])
    out = rasterization(*scene.values(), front_camera(), backend=backend)
    empty = out.alpha == 0
    assert empty.any() and (~empty).any()
    assert (out.image[empty] == 0).all() and (out.depth[empty] == 0).all()


@pytest.mark.parametrize("backend", LOCAL_BACKENDS)
def test_depth_is_the_expected_camera_depth(backend):
    """One Gaussian alone renders its own depth; two overlapping ones their weighted mean."""
    cam = front_camera()
    one = splats([[0.0, 0.5, 0.0]], [[0.05, 0.05, 0.05]], [0.7], [[1.0]])
    out = rasterization(*one.values(), cam, backend=backend)
    covered = out.alpha > 0
    assert torch.allclose(out.depth[covered], torch.full_like(out.depth[covered], 3.5), atol=1e-12)

    two = splats([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0.05] * 3] * 2, [0.6, 0.9], [[1.0], [1.0]])
    out = rasterization(*two.values(), cam, backend=backend)
    # at the image centre both cover the pixel: weights 0.6 alpha0 and 0.4 alpha1
    i, j = 12, 16
    a0 = float(out.alpha[i, j])
    assert 0.6 < a0 < 1.0
    front = float(rasterization(*{k: v[:1] for k, v in two.items()}.values(), cam, backend=backend).alpha[i, j])
    w0, w1 = front, a0 - front
    assert abs(float(out.depth[i, j]) - (3.0 * w0 + 4.0 * w1) / (w0 + w1)) < 1e-12


@pytest.mark.parametrize("backend", LOCAL_BACKENDS)
def test_first_hit_semantics(backend):
    """Gaussian 0: faint (opacity 0.3), in front, centred left of the centre. Gaussian 1: opaque,
    behind, centred on the image centre. Gaussian 2: opaque, in front of both, far to the right."""
    cam = front_camera(32, 24)
    scene = splats([[-0.05, -0.5, 0.0], [0.0, 0.0, 0.0], [0.5, -1.0, 0.0]],
                   [[0.06, 0.06, 0.06], [0.08, 0.08, 0.08], [0.03, 0.03, 0.03]],
                   [0.3, 0.95, 0.9], [[1.0], [2.0], [3.0]])
    out = rasterization(*scene.values(), cam, backend=backend, return_first_hit=True, hit_threshold=0.5)
    hit = out.first_hit
    centre_row, centre_col = 12, 16
    # faint Gaussian 0 is in front but the opacity it accumulates stays below the threshold: the
    # opaque one behind is where the ray's opacity reaches it
    assert hit[centre_row, centre_col] == 1
    # Gaussian 2 is the only one on the right
    right = hit[:, 24:]
    assert (right == 2).any() and ((right == 2) | (right == -1)).all()
    # corners see nothing
    assert hit[0, 0] == -1 and hit[-1, -1] == -1
    # near their rims the accumulated opacity stays below the threshold: no hit there
    assert ((out.alpha > 0) & (hit == -1)).any()
    # with a low threshold the faint Gaussian in front wins where it covers the centre
    low = rasterization(*scene.values(), cam, backend=backend, return_first_hit=True, hit_threshold=0.1)
    assert low.first_hit[centre_row, centre_col] == 0
    assert out.first_hit is not None
    assert rasterization(*scene.values(), cam, backend=backend).first_hit is None


@pytest.mark.parametrize("channels", [1, 4, 5, 6, 12])  # kernel paths: 2, 5, 7 (fixed counts), 6, 13 (runtime)
def test_backends_agree_end_to_end(channels):
    if "cpu" not in LOCAL_BACKENDS:
        pytest.skip("the CPU rasterizer is not available")
    cam = front_camera(40, 30)
    scene = random_gaussians(60, channels, seed=2)
    results = {}
    for backend in ("cpu", "torch"):
        leaves = {k: v.clone().requires_grad_() for k, v in scene.items()}
        out = rasterization(*leaves.values(), cam, backend=backend, return_first_hit=True)
        (out.image.sum() + (out.depth * out.alpha).sum()).backward()
        results[backend] = (out, {k: v.grad for k, v in leaves.items()})
    (cpu, cpu_grads), (ref, ref_grads) = results["cpu"], results["torch"]
    for name in ("image", "alpha", "depth"):
        assert torch.allclose(getattr(cpu, name), getattr(ref, name), atol=1e-12, rtol=0), name
    assert torch.equal(cpu.first_hit, ref.first_hit) and torch.equal(cpu.radii, ref.radii)
    for name in scene:
        assert torch.allclose(cpu_grads[name], ref_grads[name], atol=1e-11, rtol=1e-9), name


# ------------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, index", [("means", (5, 1)), ("quats", (2, 3)), ("scales", (7, 0)),
                                         ("opacities", (4,)), ("features", (9, 2)), ("background", (1,))])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_values_are_rejected(name, index, bad):
    inputs = random_gaussians(12)
    inputs["background"] = torch.zeros(3, dtype=F64)
    inputs[name][index] = bad
    second = tuple(min(i + 1, s - 1) for i, s in zip(index, inputs[name].shape))
    inputs[name][second] = bad
    count = 1 if second == index else 2
    with pytest.raises(ValueError, match=re.escape(f"{name} has {count} non-finite value(s), first at index {index}")):
        rasterization(inputs["means"], inputs["quats"], inputs["scales"], inputs["opacities"], inputs["features"],
                      front_camera(), background=inputs["background"])


def test_non_positive_scales_are_rejected():
    inputs = random_gaussians(12)
    inputs["scales"][3, 2] = 0.0
    inputs["scales"][8, 0] = -0.1
    with pytest.raises(ValueError, match=re.escape("2 value(s) are <= 0, first at index (3, 2)")):
        rasterization(*inputs.values(), front_camera())


@pytest.mark.parametrize("name, shape, expected", [
    ("means", (12, 2), "means: expected shape (N, 3), found (12, 2)"),
    ("quats", (12, 3), "quats: expected shape (12, 4), found (12, 3)"),
    ("scales", (11, 3), "scales: expected shape (12, 3), found (11, 3)"),
    ("opacities", (12, 1), "opacities: expected shape (12,), found (12, 1)"),
    ("features", (12,), "features: expected shape (12, C) with C >= 1, found (12,)"),
    ("features", (12, 0), "features: expected shape (12, C) with C >= 1, found (12, 0)"),
])
def test_wrong_shapes_are_rejected(name, shape, expected):
    inputs = random_gaussians(12)
    inputs[name] = torch.rand(shape, dtype=F64)
    with pytest.raises(ValueError, match=re.escape(expected)):
        rasterization(*inputs.values(), front_camera())


def test_wrong_background_dtype_and_backend_are_rejected():
    inputs = random_gaussians(12)
    with pytest.raises(ValueError, match=re.escape("background: expected shape (3,), found (4,)")):
        rasterization(*inputs.values(), front_camera(), background=torch.zeros(4, dtype=F64))
    with pytest.raises(ValueError, match="scales: expected dtype torch.float64"):
        rasterization(inputs["means"], inputs["quats"], inputs["scales"].float(), inputs["opacities"],
                      inputs["features"], front_camera())
    with pytest.raises(ValueError, match="means: expected dtype torch.float32 or torch.float64, found torch.float16"):
        rasterization(*(v.half() for v in inputs.values()), front_camera())
    with pytest.raises(ValueError, match="backend must be one of"):
        rasterization(*inputs.values(), front_camera(), backend="opengl")
    with pytest.raises(ValueError, match="eps2d"):
        rasterization(*inputs.values(), front_camera(), eps2d=-1.0)
    with pytest.raises(ValueError, match="near must be > 0"):
        rasterization(*inputs.values(), front_camera(), near=0.0)


# ------------------------------------------------------------------------------------------------
# backends
# ------------------------------------------------------------------------------------------------

def test_available_backends():
    found = available_backends()
    assert found[-1] == "torch"
    if "cpu" in LOCAL_BACKENDS:
        assert found[-2] == "cpu"
    if not torch.cuda.is_available():
        assert "gsplat" not in found


def test_auto_falls_back_to_torch_with_one_warning(monkeypatch):
    monkeypatch.setattr(cpu_backend, "is_available", lambda: False)
    monkeypatch.setattr(rasterize_module, "_warned_fallback", False)
    scene = random_gaussians(20)
    with pytest.warns(RuntimeWarning, match="pure-torch"):
        out = rasterization(*scene.values(), front_camera())
    want = rasterization(*scene.values(), front_camera(), backend="torch")
    assert torch.equal(out.image, want.image)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rasterization(*scene.values(), front_camera())


def test_build_cache_location_and_key(monkeypatch, tmp_path):
    monkeypatch.setenv("WONDERHUMAN_CACHE_DIR", str(tmp_path))
    assert cpu_backend.cache_root() == tmp_path
    key = cpu_backend.build_key()
    monkeypatch.setattr(cpu_backend, "_cpu_signature", lambda: "another cpu")
    assert cpu_backend.build_key() != key


@pytest.mark.gpu
def test_gsplat_backend_matches_the_cpu_kernel():
    """Opacities below 0.35 make gsplat's and our pixel sets coincide (outside a 3-sigma box alpha
    is then below 1/255) and no pixel terminates early, so the two agree to float32 rounding."""
    if not torch.cuda.is_available():
        pytest.skip("needs CUDA")
    if "gsplat" not in available_backends():
        pytest.skip("gsplat's CUDA backend does not load")
    if "cpu" not in available_backends():
        pytest.skip("the CPU rasterizer is not available")
    cam = front_camera(96, 64)
    scene = random_gaussians(300, 4, seed=3, dtype=torch.float32)
    scene["opacities"] = scene["opacities"] * 0.3 + 0.04
    background = torch.tensor([0.1, 0.2, 0.3, 0.4])
    results = {}
    for backend, device in (("gsplat", "cuda"), ("cpu", "cpu")):
        leaves = {k: v.to(device).requires_grad_() for k, v in scene.items()}
        out = rasterization(*leaves.values(), cam, background=background.to(device), backend=backend,
                            return_first_hit=True)
        (out.image.sum() + out.alpha.sum() + (out.depth * out.alpha).sum()).backward()
        results[backend] = (out, {k: v.grad.cpu() for k, v in leaves.items()})
    (gs, gs_grads), (cpu, cpu_grads) = results["gsplat"], results["cpu"]
    for name in ("image", "alpha", "depth"):
        err = float((getattr(gs, name).cpu() - getattr(cpu, name)).abs().max())
        print(f"gsplat vs cpu {name}: {err:.1e}")
        assert err < 1e-4, name
    assert torch.equal(gs.first_hit.cpu(), cpu.first_hit)
    for name in scene:
        rel = (gs_grads[name] - cpu_grads[name]).abs().max() / cpu_grads[name].abs().max()
        print(f"gsplat vs cpu grad {name}: {float(rel):.1e}")
        assert rel < 1e-3, name
