"""Randomly initialised Zero123 models of the real architecture, for tests and benchmarks.

``size="full"`` is Zero123's shape (SD 1.x UNet with 8 input channels and 768-d cross-attention,
the SD VAE, CLIP ViT-L/14's vision tower with a 768-d projection, cc_projection 772 -> 768);
``size="tiny"`` keeps the same classes, block types and data flow with a few channels, so that a
folder saved from it goes through exactly the loading and SDS code a real one does.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from .zero123_loader import CAMERA_ENTRIES, write_projection

SCHEDULER = dict(num_train_timesteps=1000, beta_start=0.00085, beta_end=0.012, beta_schedule="scaled_linear",
                 clip_sample=False, set_alpha_to_one=False, steps_offset=1, prediction_type="epsilon")

CONFIGS = {
    "full": dict(
        unet=dict(sample_size=32, in_channels=8, out_channels=4, layers_per_block=2,
                  block_out_channels=(320, 640, 1280, 1280), cross_attention_dim=768, attention_head_dim=8,
                  down_block_types=("CrossAttnDownBlock2D",) * 3 + ("DownBlock2D",),
                  up_block_types=("UpBlock2D",) + ("CrossAttnUpBlock2D",) * 3),
        vae=dict(in_channels=3, out_channels=3, latent_channels=4, layers_per_block=2, sample_size=256,
                 block_out_channels=(128, 256, 512, 512), down_block_types=("DownEncoderBlock2D",) * 4,
                 up_block_types=("UpDecoderBlock2D",) * 4, scaling_factor=0.18215),
        clip=dict(hidden_size=1024, intermediate_size=4096, num_hidden_layers=24, num_attention_heads=16,
                  image_size=224, patch_size=14, projection_dim=768, hidden_act="quick_gelu"),
    ),
    "tiny": dict(
        unet=dict(sample_size=32, in_channels=8, out_channels=4, layers_per_block=1, norm_num_groups=8,
                  block_out_channels=(16, 32), cross_attention_dim=32, attention_head_dim=4,
                  down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
                  up_block_types=("UpBlock2D", "CrossAttnUpBlock2D")),
        vae=dict(in_channels=3, out_channels=3, latent_channels=4, layers_per_block=1, sample_size=256,
                 norm_num_groups=4, block_out_channels=(8, 8, 16, 16), down_block_types=("DownEncoderBlock2D",) * 4,
                 up_block_types=("UpDecoderBlock2D",) * 4, scaling_factor=0.18215),
        clip=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=4,
                  image_size=224, patch_size=32, projection_dim=32, hidden_act="quick_gelu"),
    ),
}


def build_random(size: str = "tiny", seed: int = 0):
    """(unet, vae, image_encoder, cc_projection, scheduler), randomly initialised, float32."""
    from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection

    cfg = CONFIGS[size]
    torch.manual_seed(seed)
    unet = UNet2DConditionModel(**cfg["unet"])
    vae = AutoencoderKL(**cfg["vae"])
    clip = CLIPVisionModelWithProjection(CLIPVisionConfig(**cfg["clip"]))
    d, p = cfg["unet"]["cross_attention_dim"], cfg["clip"]["projection_dim"]
    proj = torch.nn.Linear(p + CAMERA_ENTRIES, d)
    scheduler = DDIMScheduler(**SCHEDULER)
    return unet, vae, clip, proj, scheduler


def save_random_zero123(folder: str | os.PathLike, size: str = "tiny", seed: int = 0,
                        layout: str = "cc_projection", dtype: torch.dtype | None = None) -> Path:
    """Write a random model in diffusers layout (as ``save_pretrained`` of the Zero1to3 pipeline);
    ``dtype`` casts the weights first (bf16 halves a full-size model's 4.6 GB)."""
    from transformers import CLIPVisionConfig  # noqa: F401 (fails early without the extra)

    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    unet, vae, clip, proj, scheduler = build_random(size, seed)
    if dtype is not None:
        unet, vae, clip, proj = (m.to(dtype) for m in (unet, vae, clip, proj))
    unet.save_pretrained(root / "unet")
    vae.save_pretrained(root / "vae")
    clip.save_pretrained(root / "image_encoder")
    scheduler.save_pretrained(root / "scheduler")
    write_projection(root, proj.weight, proj.bias, layout)
    fe = root / "feature_extractor"
    fe.mkdir(exist_ok=True)
    (fe / "preprocessor_config.json").write_text(json.dumps({
        "image_processor_type": "CLIPImageProcessor", "crop_size": {"height": 224, "width": 224},
        "size": {"shortest_edge": 224}, "do_normalize": True, "do_resize": True, "do_center_crop": True,
        "image_mean": [0.48145466, 0.4578275, 0.40821073], "image_std": [0.26862954, 0.26130258, 0.27577711],
        "resample": 3}, indent=2))
    proj_cls = "CCProjection" if layout == "cc_projection" else "CLIPCameraProjection"
    (root / "model_index.json").write_text(json.dumps({
        "_class_name": "Zero1to3StableDiffusionPipeline", "_diffusers_version": "0.42.1",
        "vae": ["diffusers", "AutoencoderKL"], "unet": ["diffusers", "UNet2DConditionModel"],
        "image_encoder": ["transformers", "CLIPVisionModelWithProjection"],
        "scheduler": ["diffusers", "DDIMScheduler"], "feature_extractor": ["transformers", "CLIPImageProcessor"],
        layout: ["pipeline_zero1to3", proj_cls], "safety_checker": [None, None],
        "requires_safety_checker": False}, indent=2))
    return root
