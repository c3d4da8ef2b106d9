"""Zero123 SDS step time on this machine, with randomly initialised models of the real architecture.

    python benchmarks/zero123_sds.py [--full] [--steps N] [--threads 2] [--device cpu|cuda]

Each configuration runs in its own process (peak memory is per process). ``tiny`` is the test
model, saved in diffusers layout and loaded through the loader; ``full`` is Zero123's full size
(SD 1.x UNet with 8 input channels, SD VAE, CLIP ViT-L/14 vision tower, cc_projection 772 -> 768)
built in memory (random weights: timing only), in fp32 and bf16. Prints a table: one SDS step
(loss + backward to the render) and its parts: VAE encoder forward, encoder forward+backward,
UNet forward (the CFG batch of 2), reference conditioning (CLIP + VAE, once per reference); and
the CPU seconds one SDS step uses over all threads (a number less sensitive to other jobs on a
shared machine than the wall-clock times: uncontended wall time is about it / threads).
With ``--device cuda`` the models run on the GPU, every timing waits for the GPU to finish, and
the peak is the GPU memory torch allocated (``torch.cuda.max_memory_allocated``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(cfg: dict) -> dict:
    sys.path.insert(0, str(ROOT))
    import torch

    torch.set_num_threads(cfg["threads"])
    from reconstruct.priors.base import CameraDelta, GuidanceInput
    from reconstruct.priors.zero123 import Zero123Prior
    from reconstruct.priors.zero123_loader import assemble
    from reconstruct.priors.zero123_random import build_random, save_random_zero123

    dtype = {"fp32": torch.float32, "bf16": torch.bfloat16}[cfg["dtype"]]
    device = torch.device(cfg.get("device", "cpu"))
    cuda = device.type == "cuda"
    t0 = time.perf_counter()
    if cfg["size"] == "tiny":
        with tempfile.TemporaryDirectory() as d:
            folder = save_random_zero123(Path(d) / "zero123-tiny", "tiny")
            t1 = time.perf_counter()
            prior = Zero123Prior(folder, device=device, dtype=dtype, guidance_scale=3.0, seed=0)
    else:
        unet, vae, clip, proj, sched = build_random(cfg["size"], seed=0)
        t1 = time.perf_counter()
        prior = Zero123Prior(components=assemble(unet, vae, clip, proj, sched.alphas_cumprod, device=device,
                                                 dtype=dtype), guidance_scale=3.0, seed=0)
        del unet, vae, clip
    t2 = time.perf_counter()
    c = prior.c
    n_params = sum(p.numel() for m in (c.unet, c.vae.encoder, c.image_encoder) for p in m.parameters())

    g = torch.Generator().manual_seed(0)
    ref = torch.rand(256, 256, 3, generator=g).to(device)
    render = torch.rand(256, 256, 3, generator=g).to(device).requires_grad_(True)
    delta = CameraDelta(polar=0.2, azimuth=math.pi / 2)

    def timed(fn, n):
        out = []
        for _ in range(n):
            s = time.perf_counter()
            fn()
            if cuda:
                torch.cuda.synchronize()
            out.append(time.perf_counter() - s)
        return statistics.median(out) * 1000

    ref_ms = timed(lambda: (prior.__setattr__("_ref_key", None), prior.reference_conditioning(ref)), 1)

    def sds():
        render.grad = None
        prior.loss(GuidanceInput(render=render, reference=ref, delta=delta, progress=0.5)).loss.backward()

    def enc_fwd():
        with torch.no_grad():
            prior.encode_render(render)

    def enc_fwd_bwd():
        render.grad = None
        prior.encode_render(render).sum().backward()

    z = torch.randn(2, 8, 32, 32, dtype=dtype, device=device)
    emb = torch.randn(2, 1, c.unet.config.cross_attention_dim, dtype=dtype, device=device)
    tt = torch.tensor([500, 500], device=device)

    def unet():
        with torch.no_grad():
            c.unet(z, tt, encoder_hidden_states=emb)

    sds()  # warm-up
    if cuda:
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    n = cfg["steps"]
    c0 = time.process_time()
    step_ms = timed(sds, n)
    step_cpu_s = (time.process_time() - c0) / n  # CPU seconds over all threads: ~load-independent
    finite = bool(torch.isfinite(render.grad).all())
    prior.guidance_scale = 100.0  # the stability check: a very high guidance scale stays finite
    sds()
    finite100 = bool(torch.isfinite(render.grad).all())
    prior.guidance_scale = 3.0
    res = dict(cfg, build_s=t1 - t0, load_s=t2 - t1, params_m=n_params / 1e6, ref_ms=ref_ms,
               step_ms=step_ms, step_cpu_s=step_cpu_s, enc_fwd_ms=timed(enc_fwd, max(1, n // 2)),
               enc_fwd_bwd_ms=timed(enc_fwd_bwd, max(1, n // 2)), unet_ms=timed(unet, max(1, n // 2)),
               finite=finite, finite100=finite100,
               peak_gb=(torch.cuda.max_memory_allocated() / 1024 ** 3 if cuda
                        else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="also time the full-size model (fp32 and bf16; ~6 GB, minutes)")
    ap.add_argument("--steps", type=int, default=10, help="timed SDS steps for the tiny model (full: 3)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--json", type=Path, help="also write the rows to this file")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    base = dict(threads=args.threads, device=args.device)
    cfgs = [dict(base, size="tiny", dtype=d, steps=args.steps) for d in ("fp32", "bf16")]
    if args.full:
        full_steps = 10 if args.device == "cuda" else 3
        cfgs += [dict(base, size="full", dtype=d, steps=full_steps) for d in ("fp32", "bf16")]
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE", TRANSFORMERS_VERBOSITY="error",
               DIFFUSERS_VERBOSITY="error", HF_HUB_OFFLINE="1")
    rows = []
    for cfg in cfgs:
        p = subprocess.run([sys.executable, __file__, "--child", json.dumps(cfg)], capture_output=True, text=True,
                           env=env, cwd=ROOT)
        if p.returncode != 0:
            print(f"{cfg}: failed\n{p.stderr[-2000:]}", file=sys.stderr)
            continue
        rows.append(json.loads(p.stdout.strip().splitlines()[-1]))
        print(f"done {cfg['size']} {cfg['dtype']}", file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    where = "CUDA" if args.device == "cuda" else f"CPU, {args.threads} threads"
    print(f"Zero123 SDS step on {where} (torch {__import__('torch').__version__}), random weights, "
          "256x256 render, CFG batch 2")
    head = ("model", "dtype", "params(M)", "build+load s", "ref cond ms", "VAE enc fwd ms", "enc fwd+bwd ms",
            "UNet fwd ms", "SDS step ms", "step CPU s", "peak GPU GB" if args.device == "cuda" else "peak GB", "finite (CFG 3 / 100)")
    print(" | ".join(head))
    print(" | ".join("-" * len(h) for h in head))
    for r in rows:
        print(" | ".join([r["size"], r["dtype"], f"{r['params_m']:.1f}", f"{r['build_s'] + r['load_s']:.1f}",
                          f"{r['ref_ms']:.0f}", f"{r['enc_fwd_ms']:.0f}", f"{r['enc_fwd_bwd_ms']:.0f}",
                          f"{r['unet_ms']:.0f}", f"{r['step_ms']:.0f}", f"{r['step_cpu_s']:.2f}", f"{r['peak_gb']:.2f}", f"{r['finite']} / {r['finite100']}"]))


if __name__ == "__main__":
    main()
