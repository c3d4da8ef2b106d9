"""Zero123 / Stable-Zero123 score distillation (paper Eq. 5 with Zero-1-to-3 as ε_φ).

One SDS step, as in the Zero123 training code and its SDS users (threestudio's zero123 and
stable_zero123 guidance, DreamGaussian, diffusers' community Zero1to3 pipeline):

* conditioning: the reference image's CLIP image embedding (resized to 224 bicubic, CLIP mean/std)
  concatenated with the camera vector [Δpolar, sin Δaz, cos Δaz, Δradius] (Stable Zero123: the 4th
  entry is the reference view's absolute polar angle) and projected by ``cc_projection``
  Linear(772 -> 768);
* reference latent: the VAE posterior *mode* of the reference image in [-1, 1], NOT multiplied by
  the VAE scaling factor (LDM ``encode_first_stage(x).mode()``; diffusers' pipeline_zero1to3 keeps
  the scaling commented out for that reason). The render's latent IS scaled (0.18215), as the
  diffusion model's own latents are;
* UNet input: [noisy latent, reference latent] along channels (8); classifier-free guidance with
  the unconditional branch = zero projected embedding and zero reference latent;
* t ~ U{min_step .. max_step} with min/max = 0.02/0.98 x 1000 (the max annealable with progress),
  w(t) = 1 - ᾱ_t, grad = w (ε̂ - ε), loss = 0.5 ‖z - stopgrad(z - grad)‖² / batch, so that
  ∂loss/∂z = grad; the gradient reaches the render through the VAE encoder.
"""

from __future__ import annotations

import math
import os
import torch
import torch.nn.functional as F

from ..schedule import Scheduled
from .base import GuidanceInput, GuidanceOutput, GuidancePrior, PriorError
from .zero123_loader import Zero123Components, load_zero123

VARIANTS = ("zero123", "stable-zero123")


def detect_variant(path: str | os.PathLike | None) -> str:
    """Stable Zero123 has the same architecture and files; only its camera vector differs, so
    the folder cannot tell. Like DreamGaussian, take a name containing "stable" as Stable Zero123."""
    return "stable-zero123" if path is not None and "stable" in os.path.basename(os.path.normpath(str(path))).lower() \
        else "zero123"


class Zero123Prior(GuidancePrior):
    """Zero123 SDS guidance from a diffusers-format folder.

    path: the folder (see ``zero123_loader``); or pass ``components`` already loaded/assembled.
    variant: "zero123", "stable-zero123", or "auto" (from the folder name).
    guidance_scale: classifier-free guidance scale (Zero123 SDS users: 3-5).
    t_range: (min, max) fraction of the training steps t is drawn from.
    max_step: the max fraction over Stage II's progress, a ``Scheduled`` value (annealed noise
        levels; e.g. ``Scheduled.ramp(0, 0.98, 0.5, 1)``) or anything ``Scheduled.parse`` takes
        (``[start, 0.98, 0.5, end]``); default constant ``t_range[1]``.
    seed: seeds the prior's own generator (timesteps and noise), for reproducible runs.
    fixed_timestep / fixed_noise: use these instead of drawing (tests, determinism); fixed_noise
        is a latent-shaped (1, 4, h, w) tensor.
    return_target: also decode the one-step x0 prediction for display (costs a VAE decode).
    """

    def __init__(self, path: str | os.PathLike | None = None, *, components: Zero123Components | None = None,
                 variant: str = "auto", guidance_scale: float = 3.0, t_range: tuple[float, float] = (0.02, 0.98),
                 max_step=None,
                 device: str | torch.device | None = None, dtype: torch.dtype | None = None,
                 seed: int | None = None, fixed_timestep: int | None = None,
                 fixed_noise: torch.Tensor | None = None, return_target: bool = False):
        if components is None:
            components = load_zero123(path, device=device, dtype=dtype)
        self.c = components
        self.path = path
        if variant == "auto":
            variant = detect_variant(path)
        if variant not in VARIANTS:
            raise PriorError(f"unknown Zero123 variant {variant!r}: expected one of {', '.join(VARIANTS)} or 'auto'")
        self.variant = variant
        self.name = "Stable Zero123 SDS" if variant == "stable-zero123" else "Zero123 SDS"
        if not (0.0 <= t_range[0] < t_range[1] <= 1.0):
            raise ValueError(f"t_range must satisfy 0 <= min < max <= 1, found {t_range}")
        if not math.isfinite(guidance_scale):
            raise ValueError(f"guidance_scale must be finite, found {guidance_scale}")
        self.guidance_scale = float(guidance_scale)
        self.t_range = (float(t_range[0]), float(t_range[1]))
        self.max_step = Scheduled.parse(self.t_range[1] if max_step is None else max_step)
        self.fixed_timestep = fixed_timestep
        self.fixed_noise = fixed_noise
        self.return_target = return_target
        self.generator = torch.Generator(device=self.c.device)
        if seed is not None:
            self.generator.manual_seed(seed)
        else:
            self.generator.seed()
        self._ref_key: torch.Tensor | None = None
        self._ref_cond: tuple[torch.Tensor, torch.Tensor] | None = None

    # ------------------------------------------------------------------------------------------
    def describe(self) -> str:
        where = f" from {self.path}" if self.path is not None else ""
        return f"{self.name} ({self.variant}{where}, CFG {self.guidance_scale:g}, {self.c.device.type} {self.c.dtype})"

    @property
    def image_size(self) -> int:
        return self.c.image_size

    def step_range(self, progress: float) -> tuple[int, int]:
        """(min_step, max_step) at a fraction of Stage II done."""
        n = self.c.num_train_timesteps
        lo = self.t_range[0]
        p = min(max(float(progress), 0.0), 1.0)
        hi = min(max(self.max_step.value(p), lo), 1.0)
        min_step = int(n * lo + 1e-6)  # (tolerant of 0.98 - 0.9 = 0.0799999...)
        max_step = min(max(int(n * hi + 1e-6), min_step), n - 1)
        return min_step, max_step

    def camera_vector(self, inp: GuidanceInput) -> list[float]:
        d = inp.delta
        return d.stable_zero123_vector() if self.variant == "stable-zero123" else d.zero123_vector()

    # ------------------------------------------------------------------------------------------
    def _to_batch(self, img: torch.Tensor, what: str) -> torch.Tensor:
        if img.ndim != 3 or img.shape[-1] != 3:
            raise ValueError(f"{what} must be (H, W, 3), found {tuple(img.shape)}")
        x = img.to(device=self.c.device, dtype=torch.float32).permute(2, 0, 1).unsqueeze(0)
        s = self.image_size
        if x.shape[-2:] != (s, s):
            x = F.interpolate(x, (s, s), mode="bilinear", align_corners=False, antialias=True)
        return x

    def _clip_pixels(self, x01: torch.Tensor) -> torch.Tensor:
        # the original FrozenCLIPImageEmbedder: bicubic resize (align_corners=True, no antialias)
        # of the [-1, 1] image, back to [0, 1], then CLIP's mean/std
        s = self.c.clip_size
        x = F.interpolate(x01 * 2 - 1, (s, s), mode="bicubic", align_corners=True, antialias=False)
        x = (x + 1) / 2
        mean = torch.tensor(self.c.clip_mean, device=x.device).view(1, 3, 1, 1)
        std = torch.tensor(self.c.clip_std, device=x.device).view(1, 3, 1, 1)
        return (x - mean) / std

    @torch.no_grad()
    def reference_conditioning(self, reference: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(CLIP image embedding (1, 1, P), reference latent (1, 4, h, w), unscaled), cached for
        the last reference seen."""
        x = self._to_batch(reference, "reference")
        if self._ref_key is not None and self._ref_key.shape == x.shape and torch.equal(self._ref_key, x):
            return self._ref_cond
        dt = self.c.dtype
        emb = self.c.image_encoder(pixel_values=self._clip_pixels(x).to(dt)).image_embeds
        ref_latent = self.c.vae.encode((x * 2 - 1).to(dt)).latent_dist.mode()  # NOT scaled
        self._ref_key, self._ref_cond = x.clone(), (emb.unsqueeze(1), ref_latent)
        return self._ref_cond

    def encode_render(self, render: torch.Tensor) -> torch.Tensor:
        """The render's latent (scaled like the diffusion model's latents), with gradient, float32."""
        x = self._to_batch(render, "render")
        z = self.c.vae.encode((x * 2 - 1).to(self.c.dtype)).latent_dist.mode()
        return z.float() * self.c.scaling_factor

    def _draw(self, z: torch.Tensor, progress: float) -> tuple[torch.Tensor, torch.Tensor]:
        min_step, max_step = self.step_range(progress)
        if self.fixed_timestep is not None:
            t = torch.full((z.shape[0],), int(self.fixed_timestep), dtype=torch.long, device=z.device)
        else:
            t = torch.randint(min_step, max_step + 1, (z.shape[0],), generator=self.generator, device=z.device)
        if self.fixed_noise is not None:
            noise = self.fixed_noise.to(device=z.device, dtype=torch.float32).expand_as(z)
        else:
            noise = torch.randn(z.shape, generator=self.generator, device=z.device, dtype=torch.float32)
        return t, noise

    def loss(self, inp: GuidanceInput) -> GuidanceOutput:
        c = self.c
        emb, ref_latent = self.reference_conditioning(inp.reference)
        cam = torch.tensor(self.camera_vector(inp), device=c.device, dtype=torch.float32).view(1, 1, 4)
        with torch.no_grad():
            cond = c.cc_projection(torch.cat([emb.float(), cam], dim=-1).to(c.dtype))  # (1, 1, D)

        z = self.encode_render(inp.render)  # (B, 4, h, w), grad
        b = z.shape[0]
        t, noise = self._draw(z, inp.progress)
        abar = c.alphas_cumprod[t].view(-1, 1, 1, 1)
        with torch.no_grad():
            z_t = abar.sqrt() * z.detach() + (1 - abar).sqrt() * noise
            x_in = torch.cat([z_t, z_t]).to(c.dtype)
            refs = torch.cat([ref_latent.expand(b, -1, -1, -1), torch.zeros_like(ref_latent).expand(b, -1, -1, -1)])
            embs = torch.cat([cond.expand(b, -1, -1), torch.zeros_like(cond).expand(b, -1, -1)])
            eps = c.unet(torch.cat([x_in, refs.to(c.dtype)], dim=1), torch.cat([t, t]),
                         encoder_hidden_states=embs.to(c.dtype)).sample.float()
            eps_cond, eps_uncond = eps.chunk(2)
            eps_hat = eps_uncond + self.guidance_scale * (eps_cond - eps_uncond)
            w = 1 - abar
            grad = w * (eps_hat - noise)
            bad = int((~torch.isfinite(grad)).sum())
            if bad:
                grad = torch.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)
            target = z.detach() - grad
        loss = 0.5 * (z - target).pow(2).sum() / b

        info = {"t": int(t[0]), "w": float(w.flatten()[0]), "grad_norm": float(grad.norm()),
                "guidance_scale": self.guidance_scale, "max_step": self.step_range(inp.progress)[1]}
        if bad:
            info["nonfinite_grad"] = bad
        out = GuidanceOutput(loss=loss, info=info)
        if self.return_target:
            out.target = self._decode_x0(z_t, eps_hat, abar)
        return out

    @torch.no_grad()
    def _decode_x0(self, z_t, eps_hat, abar) -> torch.Tensor:
        x0 = (z_t - (1 - abar).sqrt() * eps_hat) / abar.sqrt()
        img = self.c.vae.decode((x0 / self.c.scaling_factor).to(self.c.dtype)).sample.float()
        return ((img[0] + 1) / 2).clamp(0, 1).permute(1, 2, 0)


def load_zero123_prior(path: str | os.PathLike, **kwargs) -> Zero123Prior:
    return Zero123Prior(path, **kwargs)
