"""Zero123 SDS prior: a tiny randomly initialised model of the real architecture, saved in
diffusers layout and loaded through the same loader a real folder goes through."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from types import SimpleNamespace

import pytest
import torch
import torch.nn.functional as F

pytest.importorskip("diffusers")
pytest.importorskip("transformers")

from reconstruct.priors.base import CameraDelta, GuidanceInput, PriorError  # noqa: E402
from reconstruct.priors.zero123 import Zero123Prior, detect_variant  # noqa: E402
from reconstruct.schedule import Scheduled  # noqa: E402
from reconstruct.priors.zero123_loader import (  # noqa: E402
    LFS_MAGIC, assemble, check_zero123_folder, load_zero123, write_projection)
from reconstruct.priors.zero123_random import build_random, save_random_zero123  # noqa: E402

DELTA = CameraDelta(polar=0.2, azimuth=math.pi / 2, radius=0.0)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return save_random_zero123(tmp_path_factory.mktemp("zero123") / "zero123-tiny", size="tiny", seed=0)


@pytest.fixture(scope="module")
def components(folder):
    return load_zero123(folder, device="cpu", dtype=torch.float32)


@pytest.fixture(scope="module")
def images():
    g = torch.Generator().manual_seed(1)
    return torch.rand(256, 256, 3, generator=g), torch.rand(256, 256, 3, generator=g)


def _inp(render, reference, progress=0.0, delta=DELTA):
    return GuidanceInput(render=render, reference=reference, delta=delta, progress=progress)


def _latent(c, img):
    """The render latent, computed here independently of the prior: VAE mode x scaling factor."""
    x = img.permute(2, 0, 1)[None] * 2 - 1
    with torch.no_grad():
        return c.vae.encode(x.to(c.dtype)).latent_dist.mode().float() * c.scaling_factor


# ---------------------------------------------------------------------------------------------
# the SDS step


def test_gradient_reaches_render_and_is_finite(components, images):
    prior = Zero123Prior(components=components, seed=0)
    render = images[0].clone().requires_grad_(True)
    out = prior.loss(_inp(render, images[1], progress=0.3))
    assert out.loss.ndim == 0 and torch.isfinite(out.loss) and out.loss.item() > 0
    out.loss.backward()
    assert render.grad is not None and torch.isfinite(render.grad).all()
    assert render.grad.abs().max() > 0
    assert 20 <= out.info["t"] <= 980 and prior.name == "Zero123 SDS"
    # the models are frozen: nothing but the render collects gradient
    assert all(p.grad is None for p in components.unet.parameters())


class OracleUNet(torch.nn.Module):
    """Predicts exactly the noise that takes z_t back to z_star (a model whose prediction is
    z_star), and records what the prior fed it."""

    def __init__(self, config, alphas_cumprod, z_star):
        super().__init__()
        self.config, self.alphas, self.z_star, self.calls = config, alphas_cumprod, z_star, []

    def forward(self, sample, timestep, encoder_hidden_states):
        self.calls.append((sample.clone(), timestep.clone(), encoder_hidden_states.clone()))
        abar = self.alphas[timestep].view(-1, 1, 1, 1)
        eps = (sample[:, :4].float() - abar.sqrt() * self.z_star) / (1 - abar).sqrt()
        return SimpleNamespace(sample=eps)


@pytest.mark.parametrize("t", [50, 500, 950])
def test_gradient_vanishes_where_render_equals_prediction(components, images, t):
    r0, ref = images
    z_star = _latent(components, r0)
    oracle = OracleUNet(components.unet.config, components.alphas_cumprod, z_star)
    c = dataclasses.replace(components, unet=oracle)
    prior = Zero123Prior(components=c, fixed_timestep=t, seed=0, guidance_scale=5.0)

    render = r0.clone().requires_grad_(True)
    out = prior.loss(_inp(render, ref))
    out.loss.backward()
    assert out.loss.item() < 1e-8
    assert render.grad.abs().max() < 1e-6

    # a different render: the gradient no longer vanishes, and the loss is the analytic
    # 0.5 |w(t) sqrt(abar/(1-abar)) (z - z_star)|^2 (checks w(t), the noising and the latent scaling)
    r1 = (r0 * 0.5 + 0.25).clone().requires_grad_(True)
    out = prior.loss(_inp(r1, ref))
    out.loss.backward()
    abar = components.alphas_cumprod[t]
    expect = 0.5 * ((1 - abar) * (abar / (1 - abar)).sqrt() * (_latent(components, r1.detach()) - z_star)).pow(2).sum()
    assert out.loss.item() == pytest.approx(expect.item(), rel=1e-3)
    assert r1.grad.abs().max() > 1e-4

    # what the UNet saw: [z_t, reference latent] for the conditional half, [z_t, 0] and a zero
    # embedding for the unconditional half; the reference latent is the VAE mode, NOT scaled
    sample, ts, emb = oracle.calls[-1]
    assert sample.shape == (2, 8, 32, 32) and ts.tolist() == [t, t]
    x_ref = ref.permute(2, 0, 1)[None] * 2 - 1
    with torch.no_grad():
        ref_latent = components.vae.encode(x_ref).latent_dist.mode()
    torch.testing.assert_close(sample[0, 4:], ref_latent[0])
    assert sample[1, 4:].abs().max() == 0 and emb[1].abs().max() == 0
    torch.testing.assert_close(sample[0, :4], sample[1, :4])
    # the conditional embedding: cc_projection([CLIP image embedding, camera vector])
    x = F.interpolate(x_ref, (224, 224), mode="bicubic", align_corners=True)
    x = ((x + 1) / 2 - torch.tensor([0.48145466, 0.4578275, 0.40821073]).view(1, 3, 1, 1)) / torch.tensor(
        [0.26862954, 0.26130258, 0.27577711]).view(1, 3, 1, 1)
    with torch.no_grad():
        clip = components.image_encoder(pixel_values=x).image_embeds
        want = components.cc_projection(torch.cat([clip, torch.tensor([DELTA.zero123_vector()])], -1))
    torch.testing.assert_close(emb[0, 0], want[0], rtol=1e-4, atol=1e-5)


class ConstUNet(torch.nn.Module):
    """Returns `a` where conditioned (non-zero embedding), `b` where not."""

    def __init__(self, config, a, b):
        super().__init__()
        self.config, self.a, self.b = config, a, b

    def forward(self, sample, timestep, encoder_hidden_states):
        cond = (encoder_hidden_states.abs().flatten(1).sum(1) > 0).view(-1, 1, 1, 1)
        return SimpleNamespace(sample=torch.where(cond, self.a, self.b).expand(sample.shape[0], 4, *sample.shape[2:]))


def test_classifier_free_guidance_direction(components, images):
    noise = torch.randn(1, 4, 32, 32, generator=torch.Generator().manual_seed(3))
    c = dataclasses.replace(components, unet=ConstUNet(components.unet.config, torch.tensor(0.3), torch.tensor(-0.1)))
    s, t = 7.0, 400
    prior = Zero123Prior(components=c, guidance_scale=s, fixed_timestep=t, fixed_noise=noise)
    out = prior.loss(_inp(images[0], images[1]))
    w = 1 - components.alphas_cumprod[t]
    eps_hat = -0.1 + s * (0.3 - (-0.1))
    assert out.loss.item() == pytest.approx((0.5 * (w * (eps_hat - noise)).pow(2).sum()).item(), rel=1e-4)


def test_fixed_noise_and_seed_are_deterministic(components, images):
    a = Zero123Prior(components=components, seed=7).loss(_inp(images[0], images[1]))
    b = Zero123Prior(components=components, seed=7).loss(_inp(images[0], images[1]))
    assert a.info["t"] == b.info["t"] and a.loss.item() == b.loss.item()
    noise = torch.randn(1, 4, 32, 32)
    p = Zero123Prior(components=components, fixed_timestep=300, fixed_noise=noise)
    l1, l2 = p.loss(_inp(images[0], images[1])), p.loss(_inp(images[0], images[1]))
    assert l1.info["t"] == 300 and l1.loss.item() == l2.loss.item()


def test_max_step_schedule(components, images):
    p = Zero123Prior(components=components, seed=0, max_step=[0, 0.98, 0.3, 1])  # threestudio's 4-list
    assert p.step_range(0.0) == (20, 980)
    assert p.step_range(1.0) == (20, 300)
    assert p.step_range(0.5) == (20, 640)
    ts = [p.loss(_inp(images[0], images[1], progress=1.0)).info["t"] for _ in range(4)]
    assert all(20 <= t <= 300 for t in ts)
    q = Zero123Prior(components=components, max_step=Scheduled.ramp(0.5, 0.98, 0.08, 1.0))
    assert q.step_range(0.25) == (20, 980) and q.step_range(1.0) == (20, 80)


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_bf16_and_high_guidance_are_finite(folder, images, dtype):
    prior = Zero123Prior(folder, dtype=dtype, guidance_scale=100.0, seed=0)
    assert prior.c.dtype == dtype and next(prior.c.unet.parameters()).dtype == dtype
    render = images[0].clone().requires_grad_(True)
    for progress in (0.0, 0.9):
        out = prior.loss(_inp(render, images[1], progress=progress))
        assert torch.isfinite(out.loss) and out.loss.dtype == torch.float32
        out.loss.backward()
    assert render.grad.dtype == torch.float32 and torch.isfinite(render.grad).all() and render.grad.abs().max() > 0
    assert "nonfinite_grad" not in out.info


def test_target_for_display(components, images):
    out = Zero123Prior(components=components, seed=0, return_target=True).loss(_inp(images[0], images[1]))
    assert out.target.shape == (256, 256, 3) and 0 <= out.target.min() and out.target.max() <= 1


# ---------------------------------------------------------------------------------------------
# layouts and variants


def test_clip_camera_projection_layout_and_stable_variant(folder, components, images, tmp_path):
    other = tmp_path / "stable-zero123-diffusers"
    shutil.copytree(folder, other)
    shutil.rmtree(other / "cc_projection")
    write_projection(other, components.cc_projection.weight, components.cc_projection.bias, "clip_camera_projection")
    assert check_zero123_folder(other).projection_dir == "clip_camera_projection"
    noise = torch.randn(1, 4, 32, 32)
    a = Zero123Prior(folder, variant="zero123", fixed_timestep=500, fixed_noise=noise)
    b = Zero123Prior(other, variant="zero123", fixed_timestep=500, fixed_noise=noise)
    assert a.loss(_inp(images[0], images[1])).loss.item() == pytest.approx(b.loss(_inp(images[0], images[1])).loss.item())

    s = Zero123Prior(other)  # "stable" in the folder name
    assert s.variant == "stable-zero123" and s.name == "Stable Zero123 SDS"
    d = CameraDelta(polar=0.1, azimuth=0.5, radius=0.3, reference_polar=1.2)
    assert s.camera_vector(_inp(images[0], images[1], delta=d)) == d.stable_zero123_vector()
    assert a.camera_vector(_inp(images[0], images[1], delta=d)) == d.zero123_vector()
    assert detect_variant("/x/zero123-xl") == "zero123"


# ---------------------------------------------------------------------------------------------
# bad folders: each names the file and what was expected


@pytest.fixture
def copy(folder, tmp_path):
    dst = tmp_path / "model"
    shutil.copytree(folder, dst)
    return dst


def _err(path) -> str:
    with pytest.raises(PriorError) as e:
        load_zero123(path, device="cpu")
    return str(e.value)


def test_missing_folder(tmp_path):
    assert "not found" in _err(tmp_path / "nope") and "nope" in _err(tmp_path / "nope")
    assert "no Zero123 folder" in _err(None)


def test_raw_ckpt(tmp_path):
    ckpt = tmp_path / "105000.ckpt"
    torch.save({"state_dict": {"cc_projection.weight": torch.zeros(768, 772)}}, ckpt)
    msg = _err(ckpt)
    assert "raw checkpoint" in msg and "105000.ckpt" in msg and "convert_zero123_to_diffusers" in msg
    msg = _err(tmp_path)  # a folder holding only the .ckpt
    assert "raw checkpoint" in msg and "105000.ckpt" in msg


def test_missing_component(copy):
    shutil.rmtree(copy / "vae")
    msg = _err(copy)
    assert "missing component" in msg and "vae" in msg


def test_missing_projection_and_weights(copy):
    (copy / "unet" / "diffusion_pytorch_model.safetensors").unlink()
    msg = _err(copy)
    assert "no weights in" in msg and "unet" in msg and "diffusion_pytorch_model.safetensors" in msg
    shutil.rmtree(copy / "cc_projection")
    assert "cc_projection" in _err(copy)


def test_git_lfs_pointer(copy):
    f = copy / "unet" / "diffusion_pytorch_model.safetensors"
    f.write_bytes(LFS_MAGIC + b"\noid sha256:" + b"0" * 64 + b"\nsize 3438167536\n")
    msg = _err(copy)
    assert "Git-LFS pointer" in msg and str(f) in msg and "git lfs pull" in msg
    cfg = copy / "vae" / "config.json"
    cfg.write_bytes(LFS_MAGIC + b"\noid sha256:" + b"1" * 64 + b"\nsize 600\n")
    assert "Git-LFS pointer" in _err(copy)


def test_wrong_unet_channels(copy):
    cfg_path = copy / "unet" / "config.json"
    cfg = json.loads(cfg_path.read_text())
    cfg["in_channels"] = 4
    cfg_path.write_text(json.dumps(cfg))
    msg = _err(copy)
    assert "unet/config.json" in msg and "in_channels is 4, expected 8" in msg and "plain Stable Diffusion" in msg
    cfg["in_channels"], cfg["out_channels"] = 8, 8
    cfg_path.write_text(json.dumps(cfg))
    assert "out_channels is 8, expected 4" in _err(copy)


def test_unet_weights_disagreeing_with_config(copy):
    # config says 8 channels, the stored conv_in has 4: the library's error is passed on, named
    from safetensors.torch import load_file, save_file

    f = copy / "unet" / "diffusion_pytorch_model.safetensors"
    sd = load_file(str(f))
    sd["conv_in.weight"] = sd["conv_in.weight"][:, :4].contiguous()
    save_file(sd, str(f))
    msg = _err(copy)
    assert "cannot load" in msg and "unet" in msg


def test_mismatched_projection(copy):
    shutil.rmtree(copy / "cc_projection")
    write_projection(copy, torch.zeros(32, 40), torch.zeros(32))
    msg = _err(copy)
    assert "cc_projection/diffusion_pytorch_model.safetensors" in msg
    assert "(32, 40)" in msg and "expected (32, 36)" in msg


def test_in_memory_components_match_loaded(folder, components, images):
    # the same random seed built in memory (the path the full-size benchmark takes) gives the
    # same SDS loss as the saved-and-loaded folder
    unet, vae, clip, proj, sched = build_random("tiny", seed=0)
    mem = assemble(unet, vae, clip, proj, sched.alphas_cumprod, device="cpu", dtype=torch.float32)
    noise = torch.randn(1, 4, 32, 32)
    a = Zero123Prior(components=mem, fixed_timestep=321, fixed_noise=noise).loss(_inp(images[0], images[1]))
    b = Zero123Prior(components=components, fixed_timestep=321, fixed_noise=noise).loss(_inp(images[0], images[1]))
    assert a.loss.item() == pytest.approx(b.loss.item(), rel=1e-5)


def test_a_random_model_saved_in_bf16_loads_with_its_weights(tmp_path):
    """``save_random_zero123(dtype=bf16)`` (the GPU benchmark's full-size model at half the size)
    writes bf16 weights that load as the same model."""
    from safetensors import safe_open

    folder = save_random_zero123(tmp_path / "bf16", "tiny", seed=0, dtype=torch.bfloat16)
    with safe_open(str(folder / "unet" / "diffusion_pytorch_model.safetensors"), "pt") as f:
        dtypes = {f.get_tensor(k).dtype for k in f.keys()}
    assert dtypes == {torch.bfloat16}
    unet = build_random("tiny", seed=0)[0]
    loaded = Zero123Prior(folder, device="cpu", dtype=torch.float32).c.unet
    for (name, a), b in zip(unet.state_dict().items(), loaded.state_dict().values()):
        assert torch.equal(a.to(torch.bfloat16).float(), b), name
