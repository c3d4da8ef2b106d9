"""Check and load a diffusers-format Zero123 / Stable-Zero123 folder (the `zero123` extra).

Expected layout (what diffusers' ``save_pretrained`` writes for the community Zero1to3 pipeline,
e.g. ``kxic/zero123-xl``, or for DreamGaussian's converted copies, e.g.
``ashawkey/zero123-xl-diffusers`` and ``ashawkey/stable-zero123-diffusers``)::

    FOLDER/
      model_index.json                      (optional; read only to report the pipeline class)
      unet/config.json + diffusion_pytorch_model.{safetensors,bin}   UNet2DConditionModel, 8 input channels
      vae/config.json + diffusion_pytorch_model.{safetensors,bin}    AutoencoderKL, 4 latent channels
      image_encoder/config.json + model.safetensors|pytorch_model.bin CLIPVisionModelWithProjection
      scheduler/scheduler_config.json                               betas of the 1000 training steps
      feature_extractor/preprocessor_config.json                    (optional; CLIP mean/std, size)
      and the camera projection, Linear(projection_dim + 4 -> cross_attention_dim), in either
      cc_projection/  (diffusers community pipeline ``CCProjection``: keys projection.weight/.bias)
      clip_camera_projection/  (DreamGaussian's ``CLIPCameraProjection``: keys proj.weight/.bias)
      each with a config.json and diffusion_pytorch_model.{safetensors,bin}.

Every problem found is raised as a ``PriorError`` naming the file and what was expected and found.
Only ``torch`` is imported at module level; diffusers/transformers are imported when loading.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import torch

from .base import PriorError

LFS_MAGIC = b"version https://git-lfs.github.com/spec/v1"
RAW_CHECKPOINT_SUFFIXES = (".ckpt", ".pt", ".pth", ".safetensors", ".bin")
CONVERT_HINT = (
    "convert it with diffusers' scripts/convert_zero123_to_diffusers.py (--checkpoint_path X.ckpt "
    "--original_config_file sd-objaverse-finetune-c_concat-256.yaml --dump_path OUT --to_safetensors) "
    "or download a diffusers-format copy (see docs/zero123.md)"
)
# the camera projection, in the two layouts found in public diffusers-format Zero123 repos:
# folder name -> (key prefix in the state dict, class name written by the repo)
PROJECTION_LAYOUTS = {
    "cc_projection": ("projection.", "CCProjection"),
    "clip_camera_projection": ("proj.", "CLIPCameraProjection"),
}
DIFFUSERS_WEIGHTS = ("diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.bin",
                     "diffusion_pytorch_model.fp16.safetensors", "diffusion_pytorch_model.fp16.bin",
                     "diffusion_pytorch_model.safetensors.index.json")
TRANSFORMERS_WEIGHTS = ("model.safetensors", "pytorch_model.bin", "model.fp16.safetensors",
                        "model.safetensors.index.json", "pytorch_model.bin.index.json")
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
CAMERA_ENTRIES = 4


@dataclass
class FolderReport:
    """What ``check_zero123_folder`` found (cheap: configs and headers only, no weights loaded)."""

    path: Path
    projection_dir: str  # "cc_projection" or "clip_camera_projection"
    projection_file: Path
    unet_config: dict
    vae_config: dict
    clip_config: dict
    scheduler_config: dict
    clip_mean: tuple = CLIP_MEAN
    clip_std: tuple = CLIP_STD
    clip_size: int = 224
    pipeline_class: str | None = None
    weight_files: dict = field(default_factory=dict)  # component -> weight file

    @property
    def cross_attention_dim(self) -> int:
        return int(self.unet_config["cross_attention_dim"])

    @property
    def projection_dim(self) -> int:
        return int(self.clip_config["projection_dim"])


@dataclass
class Zero123Components:
    """The loaded models (frozen, eval mode) and the numbers the SDS step needs."""

    unet: torch.nn.Module
    vae: torch.nn.Module
    image_encoder: torch.nn.Module
    cc_projection: torch.nn.Linear
    alphas_cumprod: torch.Tensor  # (num_train_timesteps,) float32 on the device
    scaling_factor: float
    clip_mean: tuple = CLIP_MEAN
    clip_std: tuple = CLIP_STD
    clip_size: int = 224
    device: torch.device = torch.device("cpu")
    dtype: torch.dtype = torch.float32
    report: FolderReport | None = None

    @property
    def num_train_timesteps(self) -> int:
        return int(self.alphas_cumprod.shape[0])

    @property
    def image_size(self) -> int:
        """The image size the model works at (Zero123: 32 x 8 = 256)."""
        down = 2 ** (len(self.vae.config.block_out_channels) - 1)
        return int(self.unet.config.sample_size) * down


# ----------------------------------------------------------------------------------------------
# checks


def _is_lfs_pointer(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(LFS_MAGIC)) == LFS_MAGIC
    except OSError:
        return False


def _lfs_error(path: Path) -> PriorError:
    return PriorError(
        f"{path} is a Git-LFS pointer file (it starts with 'version https://git-lfs.github.com/spec/v1'), "
        f"not the file itself ({path.stat().st_size} bytes): the repository was cloned without LFS. "
        "Run `git lfs install && git lfs pull` in the folder, or download it with "
        "`huggingface-cli download REPO --local-dir FOLDER`."
    )


def _read_json(path: Path, what: str) -> dict:
    if not path.is_file():
        raise PriorError(f"missing {path}: expected the {what}")
    if _is_lfs_pointer(path):
        raise _lfs_error(path)
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise PriorError(f"{path} is not valid JSON ({e}): expected the {what}") from None
    if not isinstance(data, dict):
        raise PriorError(f"{path}: expected a JSON object (the {what}), found {type(data).__name__}")
    return data


def _weight_file(folder: Path, names: tuple[str, ...], what: str) -> Path:
    for name in names:
        p = folder / name
        if p.is_file():
            if _is_lfs_pointer(p):
                raise _lfs_error(p)
            if name.endswith(".index.json"):  # sharded: check the shards too
                index = _read_json(p, f"{what} weight index")
                for shard in sorted(set(index.get("weight_map", {}).values())):
                    sp = folder / shard
                    if not sp.is_file():
                        raise PriorError(f"missing {sp}: listed in {p} as a shard of the {what} weights")
                    if _is_lfs_pointer(sp):
                        raise _lfs_error(sp)
            elif p.stat().st_size < 1024:
                raise PriorError(f"{p} is only {p.stat().st_size} bytes: expected the {what} weights")
            return p
    found = sorted(x.name for x in folder.iterdir()) if folder.is_dir() else []
    raise PriorError(f"no weights in {folder}: expected one of {', '.join(names)} (the {what}); "
                     f"found {', '.join(found) or 'nothing'}")


def _raw_checkpoint_error(path: Path) -> PriorError:
    return PriorError(
        f"{path} is a raw checkpoint file, not a diffusers-format folder (unet/, vae/, image_encoder/, "
        f"scheduler/, cc_projection/): {CONVERT_HINT}"
    )


def check_zero123_folder(path: str | os.PathLike | None) -> FolderReport:
    """Validate a diffusers-format Zero123 folder without loading its weights."""
    if path is None or str(path).strip() == "":
        raise PriorError("no Zero123 folder given: pass the path of a diffusers-format Zero123 folder")
    root = Path(path).expanduser()
    if not root.exists():
        raise PriorError(f"Zero123 folder not found: {root} does not exist")
    if root.is_file():
        if root.suffix.lower() in RAW_CHECKPOINT_SUFFIXES or root.stat().st_size > 1 << 20:
            if _is_lfs_pointer(root):
                raise _lfs_error(root)
            raise _raw_checkpoint_error(root)
        raise PriorError(f"{root} is a file: expected a diffusers-format Zero123 folder")

    components = ("unet", "vae", "image_encoder", "scheduler")
    present = [c for c in components if (root / c).is_dir()]
    if not present:
        raw = sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in (".ckpt", ".pt", ".pth"))
        if raw:
            if _is_lfs_pointer(raw[0]):
                raise _lfs_error(raw[0])
            raise _raw_checkpoint_error(raw[0])
    missing = [c for c in components if c not in present]
    proj_dirs = [d for d in PROJECTION_LAYOUTS if (root / d).is_dir()]
    if not proj_dirs:
        missing.append("cc_projection (or clip_camera_projection)")
    if missing:
        raise PriorError(
            f"{root} is missing component folder(s) {', '.join(missing)}: a diffusers-format Zero123 folder has "
            f"unet/, vae/, image_encoder/, scheduler/ and cc_projection/ (found: "
            f"{', '.join(sorted(p.name for p in root.iterdir())) or 'nothing'})"
        )

    pipeline_class = None
    if (root / "model_index.json").exists():
        pipeline_class = _read_json(root / "model_index.json", "pipeline index").get("_class_name")

    unet_cfg = _read_json(root / "unet" / "config.json", "UNet2DConditionModel config")
    vae_cfg = _read_json(root / "vae" / "config.json", "AutoencoderKL config")
    clip_cfg = _read_json(root / "image_encoder" / "config.json", "CLIPVisionModelWithProjection config")
    sched_cfg = _read_json(root / "scheduler" / "scheduler_config.json", "scheduler config")

    weights = {
        "unet": _weight_file(root / "unet", DIFFUSERS_WEIGHTS, "UNet"),
        "vae": _weight_file(root / "vae", DIFFUSERS_WEIGHTS, "VAE"),
        "image_encoder": _weight_file(root / "image_encoder", TRANSFORMERS_WEIGHTS, "CLIP image encoder"),
    }

    # --- UNet: 4 noisy-latent + 4 reference-latent channels in, 4 out
    uc = root / "unet" / "config.json"
    in_ch, out_ch = unet_cfg.get("in_channels"), unet_cfg.get("out_channels")
    if in_ch != 8:
        extra = " (this looks like a plain Stable Diffusion UNet, not Zero123's)" if in_ch == 4 else ""
        raise PriorError(f"{uc}: in_channels is {in_ch}, expected 8 (4 noisy-latent + 4 reference-latent "
                         f"channels){extra}")
    if out_ch != 4:
        raise PriorError(f"{uc}: out_channels is {out_ch}, expected 4 (the predicted noise in latent space)")
    if not isinstance(unet_cfg.get("cross_attention_dim"), int):
        raise PriorError(f"{uc}: cross_attention_dim is {unet_cfg.get('cross_attention_dim')!r}, expected an integer "
                         "(768 for Zero123)")
    vc = root / "vae" / "config.json"
    lat = vae_cfg.get("latent_channels", 4)
    if lat != in_ch // 2:
        raise PriorError(f"{vc}: latent_channels is {lat}, expected {in_ch // 2} (half the UNet's {in_ch} input channels)")
    cc = root / "image_encoder" / "config.json"
    if not isinstance(clip_cfg.get("projection_dim"), int):
        raise PriorError(f"{cc}: projection_dim is {clip_cfg.get('projection_dim')!r}, expected an integer "
                         "(a CLIPVisionModelWithProjection config, 768 for ViT-L/14)")
    sc = root / "scheduler" / "scheduler_config.json"
    pred = sched_cfg.get("prediction_type", "epsilon")
    if pred != "epsilon":
        raise PriorError(f"{sc}: prediction_type is {pred!r}, expected 'epsilon' (Zero123 predicts the noise; "
                         "the SDS gradient w(t)(eps_hat - eps) assumes it)")

    # --- camera projection: Linear(projection_dim + 4 -> cross_attention_dim)
    proj_dir = proj_dirs[0]
    pfolder = root / proj_dir
    if (pfolder / "config.json").exists():
        _read_json(pfolder / "config.json", f"{PROJECTION_LAYOUTS[proj_dir][1]} config")
    pfile = _weight_file(pfolder, DIFFUSERS_WEIGHTS, "camera projection")
    weights[proj_dir] = pfile
    report = FolderReport(root, proj_dir, pfile, unet_cfg, vae_cfg, clip_cfg, sched_cfg,
                          pipeline_class=pipeline_class, weight_files=weights)
    w, b = _read_projection(report)
    want = (report.cross_attention_dim, report.projection_dim + CAMERA_ENTRIES)
    if tuple(w.shape) != want or (b is not None and tuple(b.shape) != (want[0],)):
        raise PriorError(
            f"{pfile}: the camera projection weight is {tuple(w.shape)}"
            f"{'' if b is None else f' (bias {tuple(b.shape)})'}, expected {want} = (unet cross_attention_dim "
            f"{want[0]}, image_encoder projection_dim {report.projection_dim} + {CAMERA_ENTRIES} camera entries)"
        )

    # --- CLIP preprocessing numbers, when the folder carries them
    fe = root / "feature_extractor" / "preprocessor_config.json"
    if fe.exists():
        fcfg = _read_json(fe, "CLIP image processor config")
        report.clip_mean = tuple(fcfg.get("image_mean", CLIP_MEAN))
        report.clip_std = tuple(fcfg.get("image_std", CLIP_STD))
        crop = fcfg.get("crop_size", 224)
        report.clip_size = int(crop.get("height", 224) if isinstance(crop, dict) else crop)
    else:
        report.clip_size = int(clip_cfg.get("image_size", 224))
    return report


def _load_state_dict(path: Path) -> dict:
    try:
        if path.name.endswith(".safetensors"):
            from safetensors.torch import load_file

            return load_file(str(path))
        if path.name.endswith(".index.json"):
            raise PriorError(f"{path}: a sharded camera projection is not expected (it has ~600k parameters)")
        return torch.load(path, map_location="cpu", weights_only=True)
    except PriorError:
        raise
    except Exception as e:  # noqa: BLE001 - any reader failure is a bad file
        raise PriorError(f"cannot read {path} ({type(e).__name__}: {e})") from None


def _read_projection(report: FolderReport) -> tuple[torch.Tensor, torch.Tensor | None]:
    sd = _load_state_dict(report.projection_file)
    prefix = PROJECTION_LAYOUTS[report.projection_dir][0]
    candidates = [prefix] + [p for p, _ in PROJECTION_LAYOUTS.values() if p != prefix] + [""]
    for p in candidates:
        if p + "weight" in sd:
            w = sd[p + "weight"]
            if w.ndim != 2:
                raise PriorError(f"{report.projection_file}: {p}weight has shape {tuple(w.shape)}, expected a 2-D "
                                 "Linear weight")
            return w, sd.get(p + "bias")
    raise PriorError(f"{report.projection_file}: no '{prefix}weight' (found keys {', '.join(sorted(sd)) or 'none'}); "
                     f"expected the {PROJECTION_LAYOUTS[report.projection_dir][1]} Linear layer")


# ----------------------------------------------------------------------------------------------
# loading


def default_device_dtype(device: str | torch.device | None = None,
                         dtype: torch.dtype | None = None) -> tuple[torch.device, torch.dtype]:
    """CUDA when available (bf16 where supported, else fp16); CPU in fp32."""
    dev = torch.device(device) if device is not None else torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if dtype is None:
        if dev.type == "cuda":
            dtype = torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16
        else:
            dtype = torch.float32
    return dev, dtype


def _import_libs():
    try:
        import diffusers  # noqa: F401
        import transformers  # noqa: F401
    except ImportError as e:
        raise PriorError(f"the Zero123 prior needs diffusers and transformers ({e}); install the extra: "
                         "pip install -e '.[zero123]'") from None


def load_zero123(path: str | os.PathLike, device: str | torch.device | None = None,
                 dtype: torch.dtype | None = None) -> Zero123Components:
    """Check the folder, then load its models frozen onto ``device`` in ``dtype``."""
    report = check_zero123_folder(path)
    _import_libs()
    from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPVisionModelWithProjection

    dev, dt = default_device_dtype(device, dtype)
    root = report.path

    def load(what, fn):
        try:
            return fn()
        except PriorError:
            raise
        except Exception as e:  # noqa: BLE001 - wrap library errors with the component named
            raise PriorError(f"cannot load {root / what} ({type(e).__name__}: {str(e).strip()[:600]})") from None

    # diffusers takes torch_dtype; the CLIP model is cast afterwards (transformers renamed the argument)
    kw = dict(local_files_only=True, low_cpu_mem_usage=False, torch_dtype=dt)
    unet = load("unet", lambda: UNet2DConditionModel.from_pretrained(root / "unet", **kw))
    vae = load("vae", lambda: AutoencoderKL.from_pretrained(root / "vae", **kw))
    clip = load("image_encoder", lambda: CLIPVisionModelWithProjection.from_pretrained(
        root / "image_encoder", local_files_only=True))
    scheduler = load("scheduler", lambda: DDIMScheduler.from_config(report.scheduler_config))
    if unet.conv_in.in_channels != 8:
        raise PriorError(f"{report.weight_files['unet']}: conv_in takes {unet.conv_in.in_channels} channels, expected 8")
    w, b = _read_projection(report)
    proj = torch.nn.Linear(w.shape[1], w.shape[0], bias=b is not None)
    with torch.no_grad():
        proj.weight.copy_(w.float())
        if b is not None:
            proj.bias.copy_(b.float())
    return assemble(unet, vae, clip, proj, scheduler.alphas_cumprod, device=dev, dtype=dt, report=report)


def assemble(unet, vae, image_encoder, cc_projection, alphas_cumprod, *, device=None, dtype=None,
             report: FolderReport | None = None) -> Zero123Components:
    """Freeze and place already-built models (used by ``load_zero123`` and for in-memory models)."""
    dev, dt = default_device_dtype(device, dtype)
    mods = []
    for m in (unet, vae, image_encoder, cc_projection):
        if next(m.parameters()).dtype != dt:
            m = m.to(dtype=dt)
        m = m.to(device=dev).eval()
        m.requires_grad_(False)
        mods.append(m)
    kw = {}
    if report is not None:
        kw = dict(clip_mean=report.clip_mean, clip_std=report.clip_std, clip_size=report.clip_size)
    return Zero123Components(
        *mods, alphas_cumprod=torch.as_tensor(alphas_cumprod, dtype=torch.float32).to(dev),
        scaling_factor=float(getattr(vae.config, "scaling_factor", 0.18215)), device=dev, dtype=dt,
        report=report, **kw,
    )


def write_projection(folder: str | os.PathLike, weight: torch.Tensor, bias: torch.Tensor | None,
                     layout: str = "cc_projection") -> Path:
    """Save a camera projection the way the public diffusers-format repos do (``layout`` is the
    subfolder name: "cc_projection" or "clip_camera_projection"). Returns the subfolder."""
    from safetensors.torch import save_file

    prefix, cls = PROJECTION_LAYOUTS[layout]
    out = Path(folder) / layout
    out.mkdir(parents=True, exist_ok=True)
    sd = {prefix + "weight": weight.detach().contiguous().cpu()}
    if bias is not None:
        sd[prefix + "bias"] = bias.detach().contiguous().cpu()
    save_file(sd, str(out / "diffusion_pytorch_model.safetensors"))
    out_dim, in_dim = weight.shape
    cfg = {"_class_name": cls}
    cfg.update({"in_channel": in_dim, "out_channel": out_dim} if layout == "cc_projection" else
               {"embedding_dim": out_dim, "additional_embeddings": in_dim - out_dim})
    (out / "config.json").write_text(json.dumps(cfg, indent=2))
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m reconstruct.priors.zero123_loader FOLDER``: check a folder, print what was found."""
    import sys

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m reconstruct.priors.zero123_loader FOLDER", file=sys.stderr)
        return 2
    try:
        r = check_zero123_folder(args[0])
    except PriorError as e:
        print(f"not usable: {e}", file=sys.stderr)
        return 1
    print(f"{r.path}: {r.pipeline_class or 'diffusers folder'}; UNet {r.unet_config.get('in_channels')} -> "
          f"{r.unet_config.get('out_channels')} channels, cross-attention {r.cross_attention_dim}; CLIP projection "
          f"{r.projection_dim}; camera projection in {r.projection_dir}/ ({r.projection_file.name}); "
          f"scheduler {r.scheduler_config.get('beta_schedule')} {r.scheduler_config.get('beta_start')}-"
          f"{r.scheduler_config.get('beta_end')}, {r.scheduler_config.get('num_train_timesteps')} steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
