"""``prepare``: a video, an image or a folder of images -> a scene folder (frames, person masks, fitted
body shape and poses, one camera).

read frames (``inputs.py``) -> find everyone, pick one person (``people.py``) -> one steady crop around them
(``crop.py``) -> detector on the crop (2D/3D keypoints, GrabCut-refined person mask) -> other people out of
the mask, small holes filled (``masks.py``) -> drop frames without a person -> fit shape, poses and camera
(``fit.py``, ``shape.py``) -> side-view lean (``lean.py``) -> the mask's soft band coloured from inside
(``matting.py``) -> write the scene folder, ``prepare_report.json``
and ``prepare_report.png`` atomically: everything goes to a hidden sibling folder that is renamed into
place only when complete.
"""

from __future__ import annotations

import json
import math
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
from .crop import EDGES, Crop, apply_crop, edge_lines, edges_cut, held_landmarks, near_edges, person_crop
from .detector import Detections, PersonDetector
from .fit import FIT_BONES, CameraGuess, FitConfig, fit_poses, measure_fit
from .hands import with_hand_keypoints
from .inputs import InputError, input_kind, read_input
from .keypoints import LANDMARK_NAMES, LANDMARK_TARGETS
from .lean import side_view
from .masks import fill_holes as fill_mask_holes
from .masks import remove_others
from .matting import decontaminate
from .people import PersonChoiceError, PersonTrack, choose_person, quarter_turns
from .report_image import (PEOPLE_IMAGE, REPORT_IMAGE, ReportFrame, pick_frames, write_people_image,
                           write_report_image)
from .shape import ShapeBasis, body_height
from .user_masks import read_user_masks
from .video import Video, working_size

REPORT_NAME = "prepare_report.json"
PEOPLE_SIZE = 640  # people are found on frames at most this large
PEOPLE_ALL_FRAMES = 40  # clips up to this many frames: people are found in every frame, else in a sample
PEOPLE_SAMPLE = 12
CROP_MARGIN = 0.08
# a landmark within this share of the working image's longer side of a frame edge that cuts the person
# off (or past it) is left out of the fit: the knees of a photo cut at the knees came back at its bottom
# row (confidence 0.23-0.30) and pulled the thighs short, the body 1.40 m tall against 1.56 m fitted to
# the whole photo (1.48 m without them)
EDGE_LANDMARK_MARGIN = 0.02
# a landmark left out at a cutting edge but inside the image holds its limb straight in the fit
# only when the detector's confidence in it is below this (past the edge it always does)
HELD_BELOW_VISIBILITY = 0.5
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


# what each of prepare's progress stages is called where a person reads it (log lines, bars)
STAGE_WORDS = {"people": "finding people", "poses": "detecting poses", "hands": "finding hands",
               "masks": "refining masks", "keypoints": "fitting to keypoints",
               "silhouette": "fitting to the silhouette"}


class _ProgressLog:
    """A detector's ``progress``: passed on to ``progress`` (stage, done, total) when one is given
    (the studio's bar, the command line's tqdm bars); else as log lines, each stage's first frame,
    then at most one line per ``every`` seconds, and its last frame ('detecting poses: 30/60
    frames, 12 s')."""

    def __init__(self, log, every: float = 5.0, progress=None) -> None:
        self.log, self.every, self.last, self.start, self.progress = log, every, {}, {}, progress

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.progress is not None:
            self.progress(stage, done, total)
            return
        now = time.perf_counter()
        first = stage not in self.start
        if first:
            self.start[stage] = now
        if first or done >= total or now - self.last.get(stage, 0.0) >= self.every:
            self.last[stage] = now
            self.log(f"{STAGE_WORDS.get(stage, stage)}: {done}/{total} frames, {now - self.start[stage]:.0f} s")


def _find_person(video: Video, names: list[str], detector: PersonDetector, person: int | None, source: str,
                 log) -> tuple[PersonTrack | None, list[int]]:
    """Everyone in (a sample of) the preview frames; the chosen person's track.
    Returns (track or None when the detector cannot tell people apart, sampled positions)."""
    T, H, W = video.frames.shape[:3]
    sample = list(range(T)) if T <= PEOPLE_ALL_FRAMES else sorted({int(round(x)) for x in np.linspace(0, T - 1, PEOPLE_SAMPLE)})
    found = detector.find_people(video.frames[sample])
    if found is None:
        if person is not None:
            raise PersonChoiceError(f"{source}: --person {person} asked for, but the {detector.name} detector "
                                    "cannot tell people apart")
        return None, sample
    track = choose_person(found, W, H, person, source)
    if track is None:
        what = f"in {names[0]}" if T == 1 else f"in any of its {T} frames"
        raise NoPersonError(f"{source}: no person found {what} (expected a front view of one person, whole body "
                            f"in view; the {detector.name} detector found none)")
    log(f"{names[sample[track.first]]}: found {track.count} {'person' if track.count == 1 else 'people'} "
        f"(numbered left to right); preparing person {track.index} ({track.choice})"
        + (f"; choose another with --person N ({PEOPLE_IMAGE} in the scene shows who is who)"
           if track.count > 1 else ""))
    return track, sample


def _people_image(path: Path, preview: Video, names: list[str], sample: list[int], track: PersonTrack) -> None:
    """``prepare_people.png``: everyone found in the first frame with people, numbered as ``--person``
    counts them, the chosen one drawn in full."""
    first = track.first
    everyone = sorted([track.per_frame[first], *track.others[first]], key=lambda c: c.center[0])
    write_people_image(path, preview.frames[sample[first]], [c.region for c in everyone], [c.box for c in everyone],
                       track.index, f"{names[sample[first]]}: {track.count} people (--person N)\n"
                       f"preparing {track.index} ({track.choice})")


def _others_in_crop(track: PersonTrack, sample: list[int], ps: float, cr: Crop, T: int) -> list[np.ndarray | None]:
    """Per frame, the other people's pixels (not the chosen person's) in the crop, or None."""
    small_crop = Crop(cr.x0 * ps, cr.y0 * ps, cr.width * ps, cr.height * ps, cr.out_width, cr.out_height)
    out: list[np.ndarray | None] = [None] * T
    for k, i in enumerate(sample):
        if not track.others[k]:
            continue
        others = np.any([c.region for c in track.others[k]], axis=0)
        if track.per_frame[k] is not None:
            others &= ~track.per_frame[k].region
        out[i] = apply_crop(others[None].astype(np.float32), small_crop, resample="nearest")[0] > 0.5
    return out


def prepare_video(video_path: str | os.PathLike, out: str | os.PathLike, *, detector: PersonDetector,
                  fit_config: FitConfig = FitConfig(), max_size: int | None = 512, every: int = 1,
                  max_frames: int | None = None, phenotype: dict | None = None, person: int | None = None,
                  crop: bool = True, fill_holes: bool = True, report_image: bool = True, turn: bool = True,
                  masks: str | os.PathLike | None = None, use_alpha: bool = True,
                  log=_log, progress=None) -> tuple[Path, dict]:
    """Make a scene folder ``out`` from a video, an image or a folder of images; returns (folder, report).
    Nothing is written unless every step succeeds. ``progress``, if given, is called as
    progress(stage, done, total) through the long steps: the detector's stages ("people", "poses",
    "masks", where it reports them) and the fit's ("keypoints", "silhouette"). The person masks are the
    user's where there are any (``masks``: a mask video, image or folder; else, with ``use_alpha``, a
    cut-out input's transparency: ``user_masks.py``), taken as they are; else the detector's, with
    other people removed and small holes filled (``fill_holes``)."""
    t0 = time.perf_counter()
    video_path = Path(video_path)
    out = check_output_folder(out)
    detector.progress = _ProgressLog(log, progress=progress)
    # two passes over the input: a small preview to find the person, then the frames at the file's own
    # resolution, cropped as they are decoded (a long 4K clip is never held in memory whole)
    preview, names = read_input(video_path, max_side=PEOPLE_SIZE, every=every, max_frames=max_frames)
    T = preview.frames.shape[0]
    W0, H0 = preview.source_size
    ps = preview.frames.shape[2] / W0  # preview pixels per source pixel
    kind = input_kind(video_path)
    log(f"{video_path}: {T} {'frame' if T == 1 else 'frames'} of {W0}x{H0}"
        + (f", {preview.fps:g} fps" if kind == "video" else ""))
    track, sample = None, []
    turns = 0
    if crop or person is not None:
        track, sample = _find_person(preview, names, detector, person, str(video_path), log)
        if turn and track is not None:
            turns, angle = quarter_turns(track)
            if turns:
                # the person lies on their side or stands on their head in the frames as stored: read
                # them turned so that they stand (the fit, the upright prior and the crop assume it)
                log(f"the person stands {abs(angle):.0f} deg from upright in the frames "
                    f"({'upside down' if turns == 2 else 'on their side'}): reading them turned "
                    f"{90 * turns} deg counter-clockwise (--no-turn keeps them as stored)")
                preview, names = read_input(video_path, max_side=PEOPLE_SIZE, every=every, max_frames=max_frames,
                                            turns=turns)
                W0, H0 = preview.source_size
                ps = preview.frames.shape[2] / W0
                track, sample = _find_person(preview, names, detector, person, str(video_path), log)
    box = None
    if track is not None and crop:
        ub = track.union_box()
        box = tuple(v / ps for v in ub)
    if box is None:
        ww, wh = working_size(W0, H0, max_size)
        cr = Crop(0.0, 0.0, float(W0), float(H0), ww, wh)
    else:
        side = max(box[2] - box[0], box[3] - box[1]) * (1 + 2 * CROP_MARGIN)
        cr = person_crop(box, W0, H0, int(min(max_size or 10 ** 6, max(64, math.ceil(side)))), margin=CROP_MARGIN)
    video, _ = read_input(video_path, every=every, max_frames=max_frames,
                          transform=lambda f: apply_crop(f[None], cr)[0], turns=turns)
    if len(video.frames) != T:
        raise InputError(f"{video_path}: gave {len(video.frames)} frames on the second reading, {T} on the first")
    frames = video.frames
    H, W = frames.shape[1:3]
    t_read = time.perf_counter()
    if box is not None:
        log(f"cropped to the person: {cr.width:.0f}x{cr.height:.0f} source pixels at ({cr.x0:.0f}, {cr.y0:.0f}) "
            f"-> {W}x{H}")
    # other people out of the image before the detector sees it (it must find the chosen one) and out of
    # the mask after (where they were found: every frame of a short clip, a sample of a long one)
    others = _others_in_crop(track, sample, ps, cr, T) if track is not None else [None] * T
    if any(o is not None for o in others):
        # filled with the frame's median colour (not black: a black silhouette still looks like a person)
        frames = frames.copy()
        for i, o in enumerate(others):
            if o is not None:
                frames[i][o] = np.median(frames[i][~o], axis=0).astype(np.uint8)
    user, mask_source = read_user_masks(masks, video_path, names=names, indices=video.indices,
                                        source_size=video.source_size, turns=turns,
                                        transform=lambda m: apply_crop(m[None], cr)[0], every=every,
                                        max_frames=max_frames, use_alpha=use_alpha, crop=cr, alpha=video.alpha)
    if user is not None:
        log(f"person masks: {mask_source} (taken as they are; the segmenter's are not used)")
    det = detector.detect(frames)
    t_det = time.perf_counter()
    holes = holes_kept = 0
    if user is not None:
        det.raw_masks, det.refine_used = det.masks, None  # the report shows where the user's differ
        det.masks = user
    else:
        masks = det.masks.copy()
        for i in range(T):
            masks[i] = remove_others(masks[i], others[i])
            if fill_holes:
                masks[i], n, k = fill_mask_holes(masks[i], image=frames[i])
                holes, holes_kept = holes + n, holes_kept + k
        det.masks = masks
        if holes:
            log(f"filled {holes} small {'hole' if holes == 1 else 'holes'} in the person masks (green in "
                f"prepare_report.png); where one is background seen through a gap (between an arm and the "
                f"body), the avatar will wear it: --no-fill-holes keeps them, --masks gives your own masks")
        if holes_kept:
            log(f"kept {holes_kept} small {'hole' if holes_kept == 1 else 'holes'} in the person masks that look "
                f"like the background round the person (a gap between an arm and the body)")
    keep, dropped = person_frames(det)
    for d in dropped:
        pos = d.pop("position")
        d["index"] = int(video.indices[pos])
        d["name"] = names[pos]
    if not keep.any():
        what = f"in {names[0]}" if T == 1 else f"in any of its {T} frames"
        raise NoPersonError(f"{video_path}: no person found {what} (expected a front view of one person, whole "
                            f"body in view; the {detector.name} detector found none)")
    if dropped:
        log(f"dropped {len(dropped)} of {T} frames without a person: "
            + ", ".join(f"{d['index']} ({d['reason']})" for d in dropped[:10]) + (" ..." if len(dropped) > 10 else ""))
    kept, hands = with_hand_keypoints(det.select(keep))
    if kept.hands is not None:
        log(f"hands fitted to the hand model's knuckles: left in {int(hands[:, 0].sum())}, right in "
            f"{int(hands[:, 1].sum())} of {len(hands)} frames (a hand missed in more than a few frames in a "
            f"row keeps the forearm's direction there)")
    # where the frame's edges cut the person off: what lies past them is guessed, never seen, and the
    # detector's landmarks at such an edge are guesses too (left out of the fit)
    cut = [edges_cut(m, cr, (W0, H0)) for m in kept.masks]
    at_edge = 0
    kept.cut = np.zeros(kept.visibility.shape, bool)
    for k, edges in enumerate(cut):
        if edges:
            near = near_edges(kept.keypoints[k], cr, (W0, H0), edges, EDGE_LANDMARK_MARGIN * max(W, H))
            at_edge += int((near & (kept.visibility[k] > 0)).sum())
            # the fit holds the limbs that end at these straight (``FitConfig.w_cut``): those past
            # the edge, or at it with the detector unsure (knees of a photo cut at the knees put on
            # its bottom row at 0.22-0.29); not a foot the photo shows at its edge with confidence
            kept.cut[k] = held_landmarks(kept.keypoints[k], kept.visibility[k], cr, (W0, H0), edges,
                                         EDGE_LANDMARK_MARGIN * max(W, H), HELD_BELOW_VISIBILITY, near=near)
            kept.visibility[k, near] = 0.0
    base_spec = BodySpec.anny(dict(phenotype or DEFAULT_PHENOTYPE), 5.0)
    body = base_spec.build()
    shape = ShapeBasis.build(dict(base_spec.params), 5.0, base_body=body,
                             stature_m=fit_config.stature_m) if fit_config.fit_shape else None
    f0 = H0 / (2.0 * math.tan(math.radians(fit_config.fov_y_deg) / 2.0))
    K = cr.intrinsics(np.array([[f0, 0.0, W0 / 2.0], [0.0, f0, H0 / 2.0], [0.0, 0.0, 1.0]]))
    guess = CameraGuess(float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
    log(f"fitting the body's {'shape and ' if shape else ''}pose to {kept.num_frames} "
        f"{'frame' if kept.num_frames == 1 else 'frames'} ...")
    fit = fit_poses(body, kept, fit_config, shape=shape, guess=guess, log=log, progress=progress)
    spec = BodySpec.anny(fit.phenotype, 5.0) if fit.phenotype else base_spec
    final_body = spec.build()
    fit.iou, fit.fit_masks = measure_fit(final_body, fit.poses, fit.camera, kept)
    shown = pick_frames(kept.num_frames)
    lean_at = sorted(set(shown) | set(pick_frames(kept.num_frames, 8)))
    sides = {k: side_view(final_body, fit.poses[k]) for k in lean_at}
    t_fit = time.perf_counter()

    indices = video.indices[keep]
    kept_names = [n for n, k in zip(names, keep) if k]
    cut_off = {e: [int(i) for i, c in zip(indices, cut) if e in c] for e in EDGES}
    cut_off = {e: v for e, v in cut_off.items() if v}
    if cut_off:
        n = kept.num_frames
        log("the frame's edge cuts the person off: " + ", ".join(
            f"{e} in {len(v)} of {n} {'frame' if n == 1 else 'frames'}" for e, v in cut_off.items())
            + f" ({at_edge} {'landmark' if at_edge == 1 else 'landmarks'} at it left out of the fit); the "
            "avatar's parts past it are guessed, not seen (film or photograph the whole body with some "
            "space round it)")
    scene_frames = []
    for k, (i, pose) in enumerate(zip(indices, fit.poses)):
        mask = kept.masks[k].astype(np.float32)
        # the soft band's colours from inside, not blended with the background (matting.py)
        image = decontaminate(frames[keep][k].astype(np.float32) / 255.0, mask) * mask[..., None]
        scene_frames.append(Frame(int(i), image, mask, fit.camera, pose, None, time=float(i) / (video.fps * every)))
    per_frame = [{"index": int(i), "name": n, "keypoint_px_error": round(float(e), 3), "silhouette_iou": round(float(u), 4)}
                 for i, n, e, u in zip(indices, kept_names, fit.keypoint_px_error, fit.iou)]
    for k, sv in sides.items():
        per_frame[k]["side_lean_deg"] = round(sv.lean_deg, 2)
    leans = np.array([sv.lean_deg for sv in sides.values()])
    report = {
        "video": str(video_path.resolve()), "input_kind": kind,
        "frames_in_video": int(T), "frames_used": int(keep.sum()), "dropped_frames": dropped,
        "image_size": [W, H], "source_size": list(video.source_size), "fps": video.fps,
        "person": None if track is None else {"picked": track.index, "people_found": track.count,
                                              "picked_by": track.picked_by},
        "crop": cr.to_dict(), "source_frame_size": [W0, H0], "turned_deg": 90 * turns, "cut_off": cut_off,
        "landmarks_at_cut_edges": at_edge,
        "masks": {"source": mask_source,
                  "refined_frames": None if kept.refine_used is None else int(kept.refine_used.sum()),
                  "holes_filled": holes, "holes_kept": holes_kept},
        "detector": detector.describe() | kept.info,
        "camera": {"focal_px": fit.camera.fx, "focal_guess_px": fit.focal_guess,
                   "principal_point": [fit.camera.cx, fit.camera.cy],
                   "fov_y_deg": float(np.degrees(fit.camera.fov_y)), "fov_y_guess_deg": fit_config.fov_y_deg,
                   "distance_m": float(np.linalg.norm(fit.camera.center)),
                   # > 0: the camera looks down at the person
                   "pitch_deg": float(np.degrees(np.arcsin(np.clip(-(fit.camera.R.T @ [0.0, 0.0, 1.0])[2], -1, 1))))},
        "body": spec.to_dict(), "body_height_m": body_height(final_body), "fitted_bones": list(FIT_BONES),
        "hands_fitted": (None if kept.hands is None
                         else {"left": int(hands[:, 0].sum()), "right": int(hands[:, 1].sum())}),
        "depth_ambiguity": fit.depth_ambiguity,
        "mean_keypoint_px_error": float(np.nanmean(fit.keypoint_px_error)),
        "mean_silhouette_iou": float(np.mean(fit.iou)),
        "side_lean_deg": {"mean": float(leans.mean()), "max_abs": float(np.abs(leans).max())},
        "per_frame": per_frame,
        "fit_config": asdict(fit_config),
        "seconds": {"read": t_read - t0, "detect": t_det - t_read, "fit": t_fit - t_det},
    }
    scene = Scene(video_path.stem, spec, scene_frames, [], video.fps, {
        "source": kind, "video": str(video_path.resolve()), "detector": detector.name,
        "dropped_frames": [d["index"] for d in dropped], "report": REPORT_NAME})
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.prepare.", dir=out.parent))
    try:
        inner = write_scene(scene, staging / "scene")
        if report_image:
            title = (f"{video_path.name}: " + ("" if track is None else f"person {track.index} of {track.count}, ")
                     + f"mean IoU {report['mean_silhouette_iou']:.3f}, height {report['body_height_m']:.2f} m, "
                     f"side lean {report['side_lean_deg']['mean']:+.1f} deg")
            lines = edge_lines(cr, (W0, H0))
            rows = [ReportFrame(kept_names[k], frames[keep][k], kept.masks[k],
                                None if kept.raw_masks is None else kept.raw_masks[k], fit.fit_masks[k],
                                float(fit.iou[k]), sides[k], {e: lines[e][0] for e in cut[k]}) for k in shown]
            if user is None:
                write_report_image(inner / REPORT_IMAGE, rows, title)
            else:
                write_report_image(inner / REPORT_IMAGE, rows, title,
                                   mask_title="your mask (green: more, red: less than the segmenter's)")
            if track is not None and track.count > 1:
                _people_image(inner / PEOPLE_IMAGE, preview, names, sample, track)
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


prepare = prepare_video


def format_report(report: dict) -> str:
    lines = [f"{'frame':>6} {'kp px err':>9} {'IoU':>6}"]
    for r in report["per_frame"]:
        lines.append(f"{r['index']:>6} {r['keypoint_px_error']:>9.2f} {r['silhouette_iou']:>6.3f}")
    cam = report["camera"]
    if report.get("person"):
        p = report["person"]
        lines.append(f"person {p['picked']} of {p['people_found']} found (numbered left to right; "
                     f"{'largest and most central' if p['picked_by'] == 'auto' else 'chosen with --person'})")
    if "body_height_m" in report:
        lean = report["side_lean_deg"]
        lines.append(f"fitted body {report['body_height_m']:.2f} m tall; side-view lean {lean['mean']:+.1f} deg "
                     f"(largest {lean['max_abs']:.1f})")
    lines.append(f"frames used {report['frames_used']} of {report['frames_in_video']}; mean keypoint error "
                 f"{report['mean_keypoint_px_error']:.2f} px, mean silhouette IoU {report['mean_silhouette_iou']:.3f} "
                 f"(fitted body vs. person mask); focal {cam['focal_px']:.1f} px (fov {cam['fov_y_deg']:.1f} deg, "
                 f"guess {cam['fov_y_guess_deg']:.1f})")
    if report["dropped_frames"]:
        lines.append("dropped frames (no person): " + ", ".join(f"{d['index']}" for d in report["dropped_frames"]))
    else:
        lines.append("dropped frames: none")
    return "\n".join(lines)
