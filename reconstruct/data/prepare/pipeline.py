"""``prepare``: a raw video -> a scene folder (frames, person masks, fitted body poses, one camera).

read frames -> detector (2D/3D keypoints, person mask per frame) -> drop frames without a person ->
fit poses and camera (``fit.py``) -> write the scene folder and ``prepare_report.json`` atomically:
everything goes to a hidden sibling folder that is renamed into place only when complete.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..scene import BodySpec, Frame, Scene
from ..scene_io import write_scene
from .detector import Detections, PersonDetector
from .fit import FIT_BONES, FitConfig, fit_poses
from .keypoints import LANDMARK_TARGETS, LANDMARK_NAMES
from .video import read_video

REPORT_NAME = "prepare_report.json"
DEFAULT_PHENOTYPE = {k: 0.5 for k in ("gender", "age", "muscle", "weight", "height", "proportions")}


class NoPersonError(ValueError):
    """No frame of the video shows a person the detector can find."""


def check_output_folder(out: str | os.PathLike) -> Path:
    """The destination may be new, empty, or a scene folder (replaced); anything else is refused."""
    out = Path(out)
    if out.exists():
        if not out.is_dir():
            raise ValueError(f"{out}: exists and is not a folder; expected a new or existing scene folder")
        if any(out.iterdir()) and not (out / "scene.json").is_file():
            raise ValueError(f"{out}: exists, is not empty and is not a scene folder (no scene.json); "
                             "refusing to replace it")
    return out


def person_frames(det: Detections, *, min_area: float = 0.002, min_landmarks: int = 6,
                  min_visibility: float = 0.5) -> tuple[np.ndarray, list[dict]]:
    """Which frames show a person: (keep mask (T,), dropped [{position, reason}])."""
    used = [LANDMARK_NAMES.index(n) for n in LANDMARK_TARGETS]
    keep = np.zeros(det.num_frames, bool)
    dropped = []
    for i in range(det.num_frames):
        area = float((det.masks[i] > 0.5).mean())
        seen = int((det.visibility[i, used] >= min_visibility).sum())
        if not det.found[i]:
            reason = "no person detected"
        elif area < min_area:
            reason = f"person mask covers {100 * area:.2f}% of the frame (< {100 * min_area:.2f}%)"
        elif seen < min_landmarks:
            reason = f"{seen} body landmarks visible (< {min_landmarks})"
        else:
            keep[i] = True
            continue
        dropped.append({"position": i, "reason": reason})
    return keep, dropped


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def prepare_video(video_path: str | os.PathLike, out: str | os.PathLike, *, detector: PersonDetector,
                  fit_config: FitConfig = FitConfig(), max_size: int | None = 512, every: int = 1,
                  max_frames: int | None = None, phenotype: dict | None = None, log=_log) -> tuple[Path, dict]:
    """Make a scene folder ``out`` from the video; returns (folder, report). Nothing is written unless
    every step succeeds."""
    t0 = time.perf_counter()
    video_path = Path(video_path)
    out = check_output_folder(out)
    video = read_video(video_path, max_size=max_size, every=every, max_frames=max_frames)
    T, H, W = video.frames.shape[:3]
    log(f"{video_path}: {T} frames at {W}x{H} ({video.source_size[0]}x{video.source_size[1]} in the file), "
        f"{video.fps:g} fps")
    t_read = time.perf_counter()
    det = detector.detect(video.frames)
    t_det = time.perf_counter()
    keep, dropped = person_frames(det)
    for d in dropped:
        d["index"] = int(video.indices[d.pop("position")])
    if not keep.any():
        raise NoPersonError(f"{video_path}: no person found in any of its {T} frames (expected a video of one "
                            f"person, whole body in view; the {detector.name} detector found none)")
    if dropped:
        log(f"dropped {len(dropped)} of {T} frames without a person: "
            + ", ".join(f"{d['index']} ({d['reason']})" for d in dropped[:10]) + (" ..." if len(dropped) > 10 else ""))
    kept = det.select(keep)
    spec = BodySpec.anny(dict(phenotype or DEFAULT_PHENOTYPE), 5.0)
    body = spec.build()
    log(f"fitting the body's pose to {kept.num_frames} frames ...")
    fit = fit_poses(body, kept, fit_config, log=log)
    t_fit = time.perf_counter()

    indices = video.indices[keep]
    frames = []
    for k, (i, pose) in enumerate(zip(indices, fit.poses)):
        mask = kept.masks[k].astype(np.float32)
        image = video.frames[keep][k].astype(np.float32) / 255.0 * mask[..., None]
        frames.append(Frame(int(i), image, mask, fit.camera, pose, None, time=float(i) / (video.fps * every)))
    per_frame = [{"index": int(i), "keypoint_px_error": round(float(e), 3), "silhouette_iou": round(float(u), 4)}
                 for i, e, u in zip(indices, fit.keypoint_px_error, fit.iou)]
    report = {
        "video": str(video_path.resolve()),
        "frames_in_video": int(T), "frames_used": int(keep.sum()), "dropped_frames": dropped,
        "image_size": [W, H], "source_size": list(video.source_size), "fps": video.fps,
        "detector": detector.describe() | kept.info,
        "camera": {"focal_px": fit.camera.fx, "focal_guess_px": fit.focal_guess,
                   "fov_y_deg": float(np.degrees(fit.camera.fov_y)), "fov_y_guess_deg": fit_config.fov_y_deg,
                   "distance_m": float(np.linalg.norm(fit.camera.center))},
        "body": spec.to_dict(), "fitted_bones": list(FIT_BONES),
        "mean_keypoint_px_error": float(np.nanmean(fit.keypoint_px_error)),
        "mean_silhouette_iou": float(np.mean(fit.iou)),
        "per_frame": per_frame,
        "fit_config": asdict(fit_config),
        "seconds": {"read": t_read - t0, "detect": t_det - t_read, "fit": t_fit - t_det},
    }
    scene = Scene(video_path.stem, spec, frames, [], video.fps, {
        "source": "video", "video": str(video_path.resolve()), "detector": detector.name,
        "dropped_frames": [d["index"] for d in dropped], "report": REPORT_NAME})
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.prepare.", dir=out.parent))
    try:
        inner = write_scene(scene, staging / "scene")
        report["seconds"]["total"] = time.perf_counter() - t0
        (inner / REPORT_NAME).write_text(json.dumps(report, indent=1))
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
            out.rename(old / "scene")
            inner.rename(out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            inner.rename(out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out, report


def format_report(report: dict) -> str:
    lines = [f"{'frame':>6} {'kp px err':>9} {'IoU':>6}"]
    for r in report["per_frame"]:
        lines.append(f"{r['index']:>6} {r['keypoint_px_error']:>9.2f} {r['silhouette_iou']:>6.3f}")
    cam = report["camera"]
    lines.append(f"frames used {report['frames_used']} of {report['frames_in_video']}; mean keypoint error "
                 f"{report['mean_keypoint_px_error']:.2f} px, mean silhouette IoU {report['mean_silhouette_iou']:.3f} "
                 f"(fitted body vs. person mask); focal {cam['focal_px']:.1f} px (fov {cam['fov_y_deg']:.1f} deg, "
                 f"guess {cam['fov_y_guess_deg']:.1f})")
    if report["dropped_frames"]:
        lines.append("dropped frames (no person): " + ", ".join(f"{d['index']}" for d in report["dropped_frames"]))
    else:
        lines.append("dropped frames: none")
    return "\n".join(lines)
