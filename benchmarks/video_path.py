"""Loose garments through the video path: a synthetic scene's training frames written to mp4 over a
light grey wall, then ``prepare`` and Stage I as a user would run them on their own video.

The benchmark's own protocol trains on the scenes' poses and cameras; a user's video goes through
the detector, the fitted body, the segmenter's masks and a guessed camera instead. Per scene this
prints what ``prepare`` fitted (keypoint error, the fitted body against the mask), the fitted body
against the scene's true body (joint error in its own camera after the mid-hip point is subtracted,
silhouette IoU against the true body's, the share of the fitted body outside the true body), the
garment layer Stage I built, and the held-out frames' PSNR / SSIM at the end of Stage I.

    python benchmarks/video_path.py OUT "synthetic:seed=1,clothing=skirt" [SPEC ...]
        [--iters 700] [--threads 1] [--detector-python .venv-video/bin/python]
        [--pose-refinement] [--set KEY=VALUE ...]

A prepared video's poses are refined by default (``Stage1Config.pose_refinement_prepared``): pass
``--set pose_refinement_prepared=false`` for the fitted poses alone (``--pose-refinement`` changes
nothing here since then).

Each scene takes ~15 min on one core (prepare 3-4 min for 60 frames, 700 steps ~11 min). OUT/NAME.mp4,
OUT/NAME_scene and OUT/NAME_run are kept; a scene whose run exists is only measured again.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruct.data.load import load_scene  # noqa: E402
from reconstruct.data.prepare.evaluate import in_prepared_frame, joint_errors, prepared_crop  # noqa: E402
from reconstruct.data.prepare.silhouette import mesh_silhouette  # noqa: E402
from reconstruct.data.scene_io import read_scene  # noqa: E402

WALL = np.array([0.82, 0.82, 0.80], np.float32)  # the wall behind the person in the video
FPS = 20.0
EVERY = 6  # silhouettes are compared on every 6th frame


def write_video(scene, path: Path) -> None:
    """The scene's frames (over black, with their masks) over the wall, to mp4."""
    from app.export import write_frames

    write_frames([f.image + (1.0 - f.mask[..., None]) * WALL for f in scene.frames], path, FPS)


def fit_against_truth(truth, folder: Path) -> dict[str, float]:
    """The prepared scene's fitted body against the synthetic scene's true body."""
    fitted = read_scene(folder)
    crop = prepared_crop(folder)
    by_index = {f.index: f for f in truth.frames}
    used = [f.index for f in fitted.frames]
    fb, tb = fitted.body_model(), truth.body_model()
    err = joint_errors(fb, [f.pose for f in fitted.frames], fitted.frames[0].camera, tb,
                       [by_index[i].pose for i in used], by_index[used[0]].camera)
    ious, outside = [], []
    with torch.no_grad():
        for f in fitted.frames[::EVERY]:
            t = by_index[f.index]
            true_sil = mesh_silhouette(tb.posed_vertices(t.pose).numpy(), tb.faces.numpy(), t.camera)
            true_sil = in_prepared_frame(true_sil, crop) > 0.5
            fit_sil = mesh_silhouette(fb.posed_vertices(f.pose).numpy(), fb.faces.numpy(), f.camera)
            ious.append((fit_sil & true_sil).sum() / max((fit_sil | true_sil).sum(), 1))
            outside.append((fit_sil & ~true_sil).sum() / max(fit_sil.sum(), 1))
    return {"joint_error_m": float(err.mean()), "body_iou": float(np.mean(ious)), "outside_body": float(np.mean(outside))}


def refined_against_truth(truth, folder: Path, run: Path) -> tuple[float, float] | None:
    """Mean joint errors (m, as ``fit_against_truth``) on the run's training frames of its refined
    poses (the fitted poses plus the corrections Stage I learned, as ``AvatarState.refined_pose``)
    and of the fitted ones; None when the run refined nothing."""
    from reconstruct.body.pose import BodyPose
    from reconstruct.train.checkpoint import load_checkpoint

    delta = load_checkpoint(run / "checkpoint_stage1.pt" if (run / "checkpoint_stage1.pt").is_file()
                            else run / "checkpoint.pt")["avatar"]["pose_delta"].numpy()
    if not np.abs(delta).any():
        return None
    fitted = read_scene(folder)
    by_index = {f.index: f for f in truth.frames}
    # the frames trained on (a held-out frame's correction stays zero)
    frames = [(k, f) for k, f in enumerate(fitted.frames) if np.abs(delta[k]).any()]
    poses = [BodyPose(f.pose.joint_rotations + delta[k][:-2], f.pose.global_orient + delta[k][-2],
                      f.pose.transl + delta[k][-1]) for k, f in frames]
    err = joint_errors(fitted.body_model(), poses, fitted.frames[0].camera, truth.body_model(),
                       [by_index[f.index].pose for _, f in frames], by_index[frames[0][1].index].camera)
    before = joint_errors(fitted.body_model(), [f.pose for _, f in frames], fitted.frames[0].camera,
                          truth.body_model(), [by_index[f.index].pose for _, f in frames],
                          by_index[frames[0][1].index].camera)
    return float(err.mean()), float(before.mean())


def held_out(run: Path) -> tuple[float, float]:
    """(PSNR, SSIM) on the held-out frames at the run's last evaluation."""
    evals = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if '"eval"' in line]
    if not evals:
        raise RuntimeError(f"{run}: no evaluation in metrics.jsonl")
    return float(evals[-1]["val_psnr"]), float(evals[-1]["val_ssim"])


def layer_line(log: str) -> str:
    """The garment layer's size and hem from the training log ('' without a layer)."""
    m = re.search(r"garment layer: [\d,]+ Gaussians \((\d+) rows x (\d+) columns\).*?hem (-?[\d.]+) m", log)
    return f"{m.group(1)} x {m.group(2)}, hem {float(m.group(3)):+.2f} m" if m else ""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("specs", nargs="+")
    ap.add_argument("--iters", type=int, default=700)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--detector-python", default=str(ROOT / ".venv-video" / "bin" / "python"))
    ap.add_argument("--pose-refinement", action="store_true", help="passed to train")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="passed to train (e.g. lr_pose=3e-4)")
    args = ap.parse_args()
    args.out = args.out.resolve()
    args.out.mkdir(parents=True, exist_ok=True)
    cli = [sys.executable, "-m", "app.cli"]
    rows = []
    for spec in args.specs:
        name = re.sub(r"[^A-Za-z0-9]+", "_", spec.split(":", 1)[-1]).strip("_")
        video, scene, run = args.out / f"{name}.mp4", args.out / f"{name}_scene", args.out / f"{name}_run"
        truth = load_scene(spec)
        log_path = args.out / f"{name}_train.log"
        if not (run / "metrics.jsonl").is_file():
            if not video.is_file():
                write_video(truth, video)
            if not scene.is_dir():
                subprocess.run(cli + ["prepare", "--detector-python", args.detector_python, str(video), "--out", str(scene)],
                               cwd=ROOT, check=True)
            with open(log_path, "w") as log:
                extra = (["--pose-refinement"] if args.pose_refinement else []) + [
                    a for kv in args.set for a in ("--set", kv)]
                subprocess.run(cli + ["train", "--scene", str(scene), "--out", str(run), "--stage", "1",
                                      "--iters", str(args.iters), "--threads", str(args.threads), *extra],
                               cwd=ROOT, check=True, stderr=log, stdout=log)
        report = json.loads((scene / "prepare_report.json").read_text())
        psnr, ssim = held_out(run)
        rows.append((spec, report["mean_keypoint_px_error"], report["mean_silhouette_iou"], fit_against_truth(truth, scene),
                     refined_against_truth(truth, scene, run),
                     layer_line(log_path.read_text(errors="replace") if log_path.is_file() else ""), psnr, ssim))
    print("| scene | keypoint error, fitted IoU vs mask | joint error, IoU vs true body, outside it "
          "| refined poses' joint error (training frames: refined / fitted) | layer | held-out PSNR, SSIM |")
    print("|---|---|---|---|---|---|")
    for spec, kp, iou, t, refined, layer, psnr, ssim in rows:
        ref = "not refined" if refined is None else f"{100 * refined[0]:.2f} / {100 * refined[1]:.2f} cm"
        print(f"| {spec} | {kp:.2f} px, {iou:.3f} | {100 * t['joint_error_m']:.2f} cm, {t['body_iou']:.3f}, "
              f"{100 * t['outside_body']:.1f} % | {ref} | {layer} | {psnr:.2f} dB, {ssim:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
