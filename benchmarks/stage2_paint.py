"""The built-in prior's pseudo-appearance measured directly: a Stage I run's avatar with the colours
of its unseen Gaussians replaced by a propagation method's, evaluated on the scene's views (seen /
unseen PSNR, SSIM, front_leak) -- the ceiling Stage II's guidance can reach with that prior.

    python benchmarks/stage2_paint.py RUN [RUN ...] [--methods stage1,diffusion,wrap] [--erosion 2]
                                      [--sheet OUT.png]

``stage1``: the Stage I colours (no repaint); ``diffusion``: the earlier screened harmonic fill
with mirrored colours (reconstruct.appearance.propagation); ``wrap``: the wrap-around fill
(reconstruct.appearance.wrap_fill). Uses the run's Stage I checkpoint when it has one.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402


class _Painted:
    """An AvatarState stand-in for ``evaluate_views``: posed Gaussians with replaced colours."""

    def __init__(self, state, colors: torch.Tensor) -> None:
        self.state, self.colors = state, colors

    def posed(self, frame: int):
        g = self.state.posed(frame)
        return dataclasses.replace(g, colors=self.colors.to(g.colors))


def load_stage1(run: Path):
    from reconstruct.run_folder import RunFolder
    from reconstruct.train.checkpoint import load_checkpoint
    from reconstruct.train.trainer import Trainer

    rf = RunFolder(run)
    if rf.stage1_checkpoint.exists():
        state = load_checkpoint(rf.stage1_checkpoint)
        scene = rf.load_scene()
        from reconstruct.train.config import Stage1Config
        trainer = Trainer(scene, Stage1Config.from_dict(state["config"]), None, scene_spec=state.get("scene_spec"))
        trainer.load_state_dict(state, str(rf.stage1_checkpoint))
        return trainer
    return rf.resume()


def method_colors(name: str, state, erosion: int) -> tuple[torch.Tensor, torch.Tensor]:
    from reconstruct.appearance.propagation import erode, propagate_colors
    from reconstruct.appearance.wrap_fill import wrap_fill_colors

    model = state.model
    nb = model.neighbours()
    trusted = torch.as_tensor(erode(state.seen.numpy(), nb, erosion))
    with torch.no_grad():
        colors = state.canonical(None).colors.detach().cpu()
    if name == "stage1":
        return colors, trusted
    if name == "diffusion":
        return propagate_colors(model.base_positions, model.parts(), trusted, colors, nb), trusted
    if name == "wrap":
        return wrap_fill_colors(model.base_positions, model.parts(), trusted, colors, nb,
                                normals=model.base_normals), trusted
    if name == "wrap_nofacing":
        return wrap_fill_colors(model.base_positions, model.parts(), trusted, colors, nb), trusted
    if name in ("oracle", "oracle_all"):
        # the scene's true albedo (synthetic scenes), scaled by the median ratio of the Stage I
        # colours to it on the seen Gaussians (the renderer's shading): what a perfect prior paints
        truth = torch.as_tensor(_true_texel_colors(state), dtype=torch.float32)
        ratio = float(torch.median((colors[trusted] + 1e-3) / (truth[trusted] + 1e-3)))
        out = colors.clone()
        repaint = ~trusted if name == "oracle" else torch.ones_like(trusted)
        out[repaint] = (truth[repaint] * ratio).clamp(0, 1)
        return out, trusted
    raise ValueError(name)


_RUN_SCENE: dict = {}


def _true_texel_colors(state) -> np.ndarray:
    from reconstruct.body.spec import BodySpec
    from reconstruct.data.synthetic.clothing import paint_clothing
    from reconstruct.data.synthetic.generator import SyntheticConfig, random_phenotype

    spec = _RUN_SCENE["spec"]
    kv = dict(x.split("=", 1) for x in spec.split(":", 1)[1].split(",") if "=" in x)
    seed = int(kv["seed"])
    cfg = SyntheticConfig(seed=seed)
    rng = np.random.default_rng(seed)
    body = BodySpec.anny(random_phenotype(rng), float(kv.get("leg_spread_deg", cfg.leg_spread_deg))).build()
    res = state.model.uv_map.resolution
    return paint_clothing(body, rng, res, kv.get("clothing", "garment")).texel_colors


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--methods", default="stage1,diffusion,wrap")
    ap.add_argument("--erosion", type=int, default=2)
    ap.add_argument("--sheet", type=Path, help="back-view sheet (truth / each method) of the first run")
    args = ap.parse_args(argv)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    from reconstruct.train.evaluate import evaluate_views

    print("| run | method | seen PSNR | unseen PSNR | unseen SSIM | front_leak | unseen Gaussians | s |")
    print("|---|---|---|---|---|---|---|---|")
    for run in args.runs:
        trainer = load_stage1(run)
        _RUN_SCENE["spec"] = json.loads((run / "run.json").read_text())["scene"]
        state = trainer.state
        sheets = []
        for m in args.methods.split(","):
            t0 = time.perf_counter()
            colors, trusted = method_colors(m, state, args.erosion)
            dt = time.perf_counter() - t0
            painted = _Painted(state, colors)
            rows, summ = evaluate_views(painted, trainer.scene, trainer.background)
            leak = summ.get("front_leak")
            print(f"| {run.name} | {m} | {summ['seen_psnr']:.2f} | {summ['unseen_psnr']:.2f} | {summ['unseen_ssim']:.4f} "
                  f"| {leak if leak is None else round(leak, 3)} | {int((~trusted).sum())} | {dt:.1f} |", flush=True)
            if args.sheet and run == args.runs[0]:
                sheets.append((m, painted))
        if sheets:
            _sheet(trainer, sheets, args.sheet)
    return 0


@torch.no_grad()
def _sheet(trainer, painted, out: Path) -> None:
    from PIL import Image

    from reconstruct.train.render import render_avatar

    views = [v for v in trainer.scene.eval_views if v.frame_index == trainer.scene.eval_views[0].frame_index]
    rows = []
    bg = trainer.background
    gt_row = [np.asarray(v.image) + (1 - np.asarray(v.mask)[..., None]) * bg.cpu().numpy() for v in views]
    rows.append(np.concatenate(gt_row, 1))
    for _, p in painted:
        rows.append(np.concatenate([render_avatar(p.posed(v.frame_index), v.camera, bg, normals=False).rgb.clamp(0, 1)
                                    .cpu().numpy() for v in views], 1))
    img = np.concatenate(rows, 0)
    Image.fromarray((img * 255).astype(np.uint8)).resize((img.shape[1] // 3, img.shape[0] // 3)).save(out)
    print(f"sheet: {out} (rows: truth, {', '.join(m for m, _ in painted)}; azimuths "
          f"{[v.azimuth_deg for v in views]})")


if __name__ == "__main__":
    raise SystemExit(main())
