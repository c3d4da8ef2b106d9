"""The CUDA path on one GPU: every check the project has for it, timed, in one run, with a report.

    python benchmarks/gpu.py all --out OUT [--stage1-minutes 1.5] [--stage2-iters 60] [--budget 480]

Needs CUDA, gsplat (its CUDA extension is built on first import) and the ``test`` and ``zero123``
extras. Sections, each in its own process (a failure is reported and the next one runs):

- ``env``      GPU, driver, torch, CUDA, gsplat versions;
- ``build``    gsplat's CUDA extension, this project's CPU kernel and the Anny body-model cache,
               built side by side while ``renderer`` runs (their build times are in the report);
- ``renderer`` the splat renderer, headless EGL on the GPU (``benchmarks/renderer.py``);
- ``tests``    the rasterizer's tests (the ``gpu``-marked gsplat comparison among them) and the whole
               path at toy size on CUDA (``tests/test_device_path.py``), printed errors kept;
- ``raster``   gsplat against the pure-torch backend on CUDA: forward and forward+backward ms, and
               gsplat with the first-hit ids Stage I asks for at every step (they come from the
               pure-torch compositor);
- ``stage1``   Stage I on the default synthetic scene with ``--device cuda`` at a 256² and the
               paper's 512² positional map: steps/s, seen/unseen PSNR against wall time, peak memory;
- ``zero123``  ``benchmarks/zero123_sds.py --full --device cuda``: full-size random Zero123, fp32/bf16;
- ``stage2``   Stage II of the 256² run, with the built-in prior and with that full-size random
               Zero123 (bf16), for a fixed number of steps each: steps/s, peak memory;
- ``stage1_skirt`` / ``stage2_skirt``  the same on a loose-clothing scene (the garment layer's path).

``OUT/report.md`` collects the tables; ``OUT/stage1_psnr_vs_time.png`` plots the curves. The
``--budget`` (seconds) stops starting sections that would not finish in it.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # first: this folder's renderer.py must not shadow the package

SCENE = "synthetic:seed=0"


def _sh(cmd: list[str], log: Path, timeout: float) -> tuple[int, float]:
    t0 = time.perf_counter()
    with open(log, "w") as f:
        try:
            rc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            rc = 124
    return rc, time.perf_counter() - t0


# ------------------------------------------------------------------------------------------ children
def child_env(out: Path) -> None:
    import torch

    info = {"torch": torch.__version__, "cuda": torch.version.cuda, "python": sys.version.split()[0]}
    if torch.cuda.is_available():
        p = torch.cuda.get_device_properties(0)
        info.update(gpu=p.name, memory_gb=round(p.total_memory / 1024 ** 3, 1), sms=p.multi_processor_count,
                    capability=f"{p.major}.{p.minor}")
    try:
        q = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                           capture_output=True, text=True, timeout=30)
        info["driver"] = q.stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        info["driver"] = None
    for name in ("gsplat", "diffusers", "transformers", "moderngl", "numpy"):
        try:
            info[name] = __import__(name).__version__
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            info[name] = f"missing ({type(exc).__name__})"
    (out / "env.json").write_text(json.dumps(info, indent=1))
    print(json.dumps(info))


def child_raster(out: Path) -> None:
    import torch

    from reconstruct.camera import Camera
    from reconstruct.raster import rasterization

    rows = []
    for n in (65536, 262144):
        for size in (512, 1024):
            g = torch.Generator().manual_seed(0)
            means = (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([0.6, 0.3, 1.7]) + torch.tensor([0, 0, 3.0])
            leaves = dict(means=means, quats=torch.randn(n, 4, generator=g),
                          scales=torch.rand(n, 3, generator=g) * 0.01 + 0.002,
                          opacities=torch.rand(n, generator=g) * 0.9 + 0.05, features=torch.rand(n, 3, generator=g))
            cam = Camera.look_at((0, 0, 0), (0, 0, 3.0), (0, -1, 0), fov_y_deg=40.0, width=size, height=size)
            for backend, first_hit in (("gsplat", False), ("gsplat", True), ("torch", False)):
                if backend == "torch" and (n > 65536 or size > 512):
                    continue  # the pure-torch backend's pair lists grow past sense here
                x = {k: v.cuda().requires_grad_() for k, v in leaves.items()}
                times = {"fwd": [], "fwd_bwd": []}
                for it in range(6):
                    for what in ("fwd", "fwd_bwd"):
                        torch.cuda.synchronize()
                        t0 = time.perf_counter()
                        o = rasterization(*x.values(), cam, backend=backend, return_first_hit=first_hit)
                        if what == "fwd_bwd":
                            (o.image.sum() + o.alpha.sum()).backward()
                        torch.cuda.synchronize()
                        if it > 0:
                            times[what].append((time.perf_counter() - t0) * 1000)
                row = dict(backend=backend + (" + first hit" if first_hit else ""), gaussians=n, size=size,
                           fwd_ms=sorted(times["fwd"])[len(times["fwd"]) // 2],
                           fwd_bwd_ms=sorted(times["fwd_bwd"])[len(times["fwd_bwd"]) // 2])
                rows.append(row)
                print(json.dumps(row), flush=True)
    (out / "raster.json").write_text(json.dumps(rows, indent=1))


def child_train(out: Path, name: str, argv: list[str]) -> None:
    """One ``train`` command in this process, so that its peak GPU memory can be read."""
    import torch

    from app.cli import main

    t0 = time.perf_counter()
    rc = main(argv)
    wall = time.perf_counter() - t0
    res = dict(name=name, argv=argv, rc=rc, wall_s=wall, peak_gb=torch.cuda.max_memory_allocated() / 1024 ** 3,
               reserved_gb=torch.cuda.max_memory_reserved() / 1024 ** 3)
    (out / f"{name}.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res))


def child_save_zero123(folder: Path) -> None:
    import torch

    from reconstruct.priors.zero123_random import save_random_zero123

    t0 = time.perf_counter()
    save_random_zero123(folder, "full", dtype=torch.bfloat16)
    print(f"saved a full-size random Zero123 (bf16) in {time.perf_counter() - t0:.1f} s")


# ------------------------------------------------------------------------------------------ report
def _metrics(run: Path) -> list[dict]:
    path = run / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def _stage_summary(run: Path, stage: int) -> dict:
    rows = [r for r in _metrics(run) if r.get("stage") == stage]
    train = [r for r in rows if r["kind"] == "train"]
    evals = [r for r in rows if r["kind"] == "eval"]
    s: dict = {"steps": train[-1]["stage_step"] if train else 0}
    if len(train) >= 2:  # a record every 25 steps; from the first fifth on (past warm-up and autotuning)
        a, b = train[len(train) // 5], train[-1]
        s["steps_per_s"] = (b["stage_step"] - a["stage_step"]) / max(b["elapsed"] - a["elapsed"], 1e-9)
        s["gaussians"] = train[-1].get("gaussians_decoded")
    if evals:
        s["curve"] = [(e["elapsed"], e["seen_psnr"], e["unseen_psnr"]) for e in evals]
        s["seen_psnr"], s["unseen_psnr"] = evals[-1]["seen_psnr"], evals[-1]["unseen_psnr"]
    return s


def write_report(out: Path, sections: dict) -> None:
    lines = ["# CUDA path: measured", ""]
    env = json.loads((out / "env.json").read_text()) if (out / "env.json").is_file() else {}
    lines += ["| " + " | ".join(f"{k}: {v}" for k, v in env.items()) + " |", "", "## Sections", "",
              "| section | rc | seconds |", "|---|---|---|"]
    lines += [f"| {k} | {v['rc']} | {v['s']:.1f} |" for k, v in sections.items()]
    if (out / "raster.json").is_file():
        lines += ["", "## Rasterizer on CUDA (median ms)", "", "| backend | Gaussians | size | forward | forward+backward |",
                  "|---|---|---|---|---|"]
        for r in json.loads((out / "raster.json").read_text()):
            lines.append(f"| {r['backend']} | {r['gaussians']} | {r['size']}² | {r['fwd_ms']:.2f} | {r['fwd_bwd_ms']:.2f} |")
    curves = {}
    lines += ["", "## Training on CUDA", "", "| run | stage | steps | steps/s | ms per step | Gaussians | "
              "seen / unseen PSNR (last eval) | peak / reserved GPU GB | wall s |", "|---|---|---|---|---|---|---|---|---|"]
    for name in ("stage1_256", "stage1_512", "stage1_skirt", "stage2_builtin", "stage2_zero123", "stage2_skirt"):
        info_path = out / f"{name}.json"
        if not info_path.is_file():
            continue
        info = json.loads(info_path.read_text())
        stage = int(name[5])
        s = _stage_summary(out / "runs" / name, stage)
        if stage == 1 and "curve" in s:
            curves[name] = s["curve"]
        rate = s.get("steps_per_s", float("nan"))
        psnr = f"{s['seen_psnr']:.2f} / {s['unseen_psnr']:.2f}" if "seen_psnr" in s else "-"
        lines.append(f"| {name} | {stage} | {s.get('steps', 0)} | {rate:.2f} | {1000 / rate:.0f} | "
                     f"{s.get('gaussians')} | {psnr} | {info['peak_gb']:.2f} / {info['reserved_gb']:.2f} | "
                     f"{info['wall_s']:.0f} (rc {info['rc']}) |")
    for name in ("renderer", "tests", "zero123"):
        log = out / f"{name}.log"
        if log.is_file():
            text = log.read_text(errors="replace").splitlines()
            keep = [t for t in text if "|" in t or "gsplat vs cpu" in t or "passed" in t or "failed" in t
                    or t.startswith("#") or "FPS" in t or "GL" in t][-60:]
            lines += ["", f"## {name}", "", "```", *keep, "```"]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    if curves:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.6))
        for name, c in curves.items():
            t = [x[0] for x in c]
            ax.plot(t, [x[1] for x in c], "-o", label=f"{name} seen")
            ax.plot(t, [x[2] for x in c], "--o", label=f"{name} unseen")
        ax.set_xlabel("training time (s, the stage clock)")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title("Stage I on CUDA, synthetic seed 0")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "stage1_psnr_vs_time.png", dpi=110)


# ------------------------------------------------------------------------------------------ driver
def run_all(args) -> int:
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    runs = out / "runs"
    runs.mkdir(exist_ok=True)
    start = time.perf_counter()
    me = [sys.executable, str(Path(__file__).resolve())]
    sections: dict[str, dict] = {}

    def left() -> float:
        return args.budget - (time.perf_counter() - start)

    wanted = set(args.sections.split(",")) if args.sections else None

    def section(name: str, cmd: list[str], need: float, timeout: float) -> int:
        if name != "env" and wanted is not None and name.split("_")[0] not in wanted and name not in wanted:
            return -1
        if left() < need:
            print(f"[gpu] skipping {name}: {left():.0f} s left, needs ~{need:.0f}", flush=True)
            return -1
        print(f"[gpu] {name} ...", flush=True)
        rc, s = _sh(cmd, out / f"{name}.log", min(timeout, max(left(), 1)))
        sections[name] = {"rc": rc, "s": s}
        print(f"[gpu] {name}: rc {rc} in {s:.1f} s", flush=True)
        write_report(out, sections)
        return rc

    section("env", me + ["--child", "env", "--out", str(out)], 5, 60)
    builds = {
        "build_gsplat": "from gsplat.cuda._backend import _C; assert _C is not None; print('gsplat', _C)",
        "build_cpu_kernel": "from reconstruct.raster import cpu_backend; cpu_backend.load_extension(); print('ok')",
        "build_anny": "from reconstruct.body.anny_backend import load_anny_model; load_anny_model(); print('ok')",
    }
    procs = {}
    for name, code in builds.items():
        f = open(out / f"{name}.log", "w")
        procs[name] = (subprocess.Popen([sys.executable, "-c", code], stdout=f, stderr=subprocess.STDOUT, cwd=ROOT),
                       time.perf_counter(), f)
    section("renderer", [sys.executable, "benchmarks/renderer.py", "--counts", "65536", "262144", "--sizes", "1024",
                         "--modes", "rgb", "depth", "--frames", "20"], 20, 150)
    for name, (p, t0, f) in procs.items():
        try:
            rc = p.wait(timeout=max(left() - 60, 1))
        except subprocess.TimeoutExpired:
            p.kill()
            rc = 124
        f.close()
        sections[name] = {"rc": rc, "s": time.perf_counter() - t0}
        print(f"[gpu] {name}: rc {rc} in {sections[name]['s']:.1f} s", flush=True)
    write_report(out, sections)

    section("tests", [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", "-rs",
                      "tests/test_raster_api.py", "tests/test_raster_projection.py", "tests/test_device_path.py"],
            30, 180)
    section("raster", me + ["--child", "raster", "--out", str(out)], 20, 90)
    minutes = str(args.stage1_minutes)
    common = ["train", "--device", args.device, "--minutes", minutes, "--iters", "100000",
              "--eval-every", str(max(10.0, 60 * args.stage1_minutes / 6)), "--quiet"]
    need = 60 * args.stage1_minutes + 40

    def stage1(res: int, name: str | None = None, scene: str = SCENE) -> None:
        name = name or f"stage1_{res}"
        argv = common + ["--out", str(runs / name), "--gaussian-res", str(res), "--scene", scene]
        section(name, me + ["--child", "train", "--name", name, "--out", str(out), "--argv", json.dumps(argv)],
                need, need + 120)

    def stage2(name: str, source: str, extra: list[str], need_s: float) -> None:
        """Stage II continuing a Stage I run of this command (in a copy: each Stage II its own)."""
        if not (runs / source / "checkpoint.pt").is_file():
            return
        shutil.copytree(runs / source, runs / name, dirs_exist_ok=True)
        argv = ["train", "--out", str(runs / name), "--stage", "2", "--device", args.device, "--quiet"] + extra
        section(name, me + ["--child", "train", "--name", name, "--out", str(out), "--argv", json.dumps(argv)],
                need_s, need_s + 240)

    stage1(256)
    stage2("stage2_builtin", "stage1_256", ["--stage2-iters", str(5 * args.stage2_iters)], 60)
    section("zero123", [sys.executable, "benchmarks/zero123_sds.py", "--full", "--device", args.device, "--steps", "5",
                        "--json", str(out / "zero123.json")], 60, 240)
    z = Path(os.environ.get("TMPDIR", "/tmp")) / "zero123-full-random"
    if (runs / "stage1_256" / "checkpoint.pt").is_file() and section(
            "stage2_save_zero123", me + ["--child", "save_zero123", "--out", str(z)], 60, 180) == 0:
        stage2("stage2_zero123", "stage1_256", ["--prior", "zero123", "--prior-path", str(z), "--stage2-iters",
                                                str(args.stage2_iters)], 40)
    stage1(256, "stage1_skirt", "synthetic:seed=0,clothing=skirt")  # the garment layer's path
    stage2("stage2_skirt", "stage1_skirt", ["--stage2-iters", str(5 * args.stage2_iters)], 60)
    stage1(512)
    write_report(out, sections)
    print((out / "report.md").read_text())
    print(f"[gpu] all sections in {time.perf_counter() - start:.0f} s")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("command", nargs="?", default="all", choices=["all", "report"])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--stage1-minutes", type=float, default=1.5)
    ap.add_argument("--stage2-iters", type=int, default=60)
    ap.add_argument("--budget", type=float, default=480.0, help="seconds; sections that would overrun are skipped")
    ap.add_argument("--sections", default=None,
                    help="comma-separated: renderer,tests,raster,stage1,stage1_256,stage1_512,stage1_skirt,zero123,"
                         "stage2,stage2_builtin,stage2_zero123,stage2_skirt "
                         "(env and the builds always run; default all)")
    ap.add_argument("--device", default="cuda", choices=["cuda", "cpu"],
                    help="cpu: a dry run of the plumbing on a machine without a GPU (short settings)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--name", help=argparse.SUPPRESS)
    ap.add_argument("--argv", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child == "env":
        child_env(args.out)
    elif args.child == "raster":
        child_raster(args.out)
    elif args.child == "train":
        child_train(args.out, args.name, json.loads(args.argv))
    elif args.child == "save_zero123":
        child_save_zero123(args.out)
    elif args.command == "report":
        write_report(args.out, {})
    else:
        return run_all(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
