"""Run mediapipe's legacy Pose solution over frames; a standalone script for the detector's interpreter.

    python mediapipe_worker.py IN.npz OUT.npz [--model-complexity 0|1] [--refine] [--mode pose|people]

IN.npz holds ``images`` (T,H,W,3) uint8 RGB. OUT.npz gets ``found`` (T,) bool, ``landmarks`` (T,33,4)
(x, y normalised to [0,1] by the image width/height, z relative depth, visibility), ``world``
(T,33,4) (metres, hip-centred, x right, y down, z away from the camera; visibility), ``masks``
(T,H,W) uint8 person segmentation (0..255) and ``version`` (the mediapipe version).

``--refine`` also writes ``raw_masks`` and refines ``masks`` with GrabCut (``grabcut_refine.py``, OpenCV)
seeded by the segmentation and the landmarks; ``refine_used`` (T,) says where the refinement was kept.

``--mode people`` finds everyone in each image instead (the legacy Pose solution tracks one person):
detect, blank out the person found, detect again, up to ``--max-people``; an image where the whole
frame shows nobody is searched again in square windows (``detect_one``). OUT.npz gets ``count`` (T,),
``people`` (T,P,33,4) normalised landmarks, ``regions`` (T,P,H,W) uint8 each person's segmentation.

This file imports only numpy and mediapipe (``mediapipe==0.10.21``, the last release whose wheel ships
the pose and segmentation models), so it can run in a separate virtualenv with ``numpy<2`` as that
release declares. It must not import the project (no torch there).
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

NUM_LANDMARKS = 33


def report(args, stage: str, done: int, total: int) -> None:
    """One progress line on stdout (with ``--progress``): 'progress STAGE DONE TOTAL'."""
    if getattr(args, "progress", False):
        print(f"progress {stage} {done} {total}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("inp")
    ap.add_argument("out")
    ap.add_argument("--model-complexity", type=int, default=1, choices=[0, 1],
                    help="0 lite, 1 full (both ship in the wheel; 2 'heavy' would be downloaded)")
    ap.add_argument("--min-detection-confidence", type=float, default=0.5)
    ap.add_argument("--refine", action="store_true", help="refine the masks with GrabCut (OpenCV)")
    ap.add_argument("--mode", choices=["pose", "people"], default="pose")
    ap.add_argument("--max-people", type=int, default=6)
    ap.add_argument("--progress", action="store_true",
                    help="print 'progress STAGE DONE TOTAL' lines on stdout as frames are done")
    args = ap.parse_args(argv)

    import numpy as np

    try:
        import mediapipe as mp
        from mediapipe.python.solutions import pose as mp_pose
    except Exception as exc:  # noqa: BLE001 - report any import failure with the interpreter
        print(f"mediapipe cannot be imported by {sys.executable}: {exc!r}", file=sys.stderr)
        return 3

    with np.load(args.inp) as z:
        images = z["images"]
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        print(f"{args.inp}: expected images (T,H,W,3) uint8, found {images.shape} {images.dtype}", file=sys.stderr)
        return 2
    T, H, W = images.shape[:3]
    if args.mode == "people":
        return find_people(images, args, mp, mp_pose)
    found = np.zeros(T, bool)
    landmarks = np.zeros((T, NUM_LANDMARKS, 4), np.float32)
    world = np.zeros((T, NUM_LANDMARKS, 4), np.float32)
    masks = np.zeros((T, H, W), np.uint8)
    with mp_pose.Pose(static_image_mode=False, model_complexity=args.model_complexity, smooth_landmarks=True,
                      enable_segmentation=True, smooth_segmentation=True,
                      min_detection_confidence=args.min_detection_confidence,
                      min_tracking_confidence=0.5) as pose:
        for i in range(T):
            result = pose.process(np.ascontiguousarray(images[i]))
            report(args, "poses", i + 1, T)
            if result.pose_landmarks is None:
                continue
            found[i] = True
            landmarks[i] = [[p.x, p.y, p.z, p.visibility] for p in result.pose_landmarks.landmark]
            if result.pose_world_landmarks is not None:
                world[i] = [[p.x, p.y, p.z, p.visibility] for p in result.pose_world_landmarks.landmark]
            if result.segmentation_mask is not None:
                masks[i] = np.clip(result.segmentation_mask * 255.0 + 0.5, 0, 255).astype(np.uint8)
    extra = {}
    if args.refine:
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from grabcut_refine import refine_mask

        raw = masks.copy()
        used = np.zeros(T, bool)
        for i in range(T):
            report(args, "masks", i + 1, T)
            if not found[i]:
                continue
            kp = landmarks[i, :, :2] * np.array([W, H], np.float32)
            m, info = refine_mask(images[i], raw[i].astype(np.float32) / 255.0, kp, landmarks[i, :, 3])
            masks[i] = np.clip(m * 255.0 + 0.5, 0, 255).astype(np.uint8)
            used[i] = info["used"]
        extra = {"raw_masks": raw, "refine_used": used}
    tmp = args.out + ".part.npz"
    np.savez(tmp, found=found, landmarks=landmarks, world=world, masks=masks, version=np.array(mp.__version__),
             **extra)
    os.replace(tmp, args.out)
    return 0


def _box(lm, W: int, H: int) -> tuple[int, int, int, int]:
    """Pixel box (x0, y0, x1, y1) around a person's landmarks ((33,4) normalised), grown to cover the head
    and the feet."""
    import numpy as np

    seen = lm[:, 3] >= 0.3
    pts = lm[seen if seen.sum() >= 4 else slice(None), :2] * np.array([W, H])
    x0, y0 = pts.min(0)
    x1, y1 = pts.max(0)
    h = max(y1 - y0, 1.0)
    return (int(max(0, x0 - 0.12 * h)), int(max(0, y0 - 0.2 * h)), int(min(W, x1 + 0.12 * h)),
            int(min(H, y1 + 0.08 * h)))


# square windows tried, as a share of the image's shorter side, when the whole image shows nobody: the
# legacy Pose detector fits the whole image into its square input, so in a wide frame a person at a
# third of its height (a landscape photo taken from a distance) was too small to be found
WINDOWS = (1.0, 0.6)


def window_origins(length: int, side: int) -> list[int]:
    """Where windows ``side`` pixels long start along an axis ``length`` pixels long: evenly spaced,
    at most half a window apart, the first at 0 and the last at the end."""
    import math

    if side >= length:
        return [0]
    n = math.ceil((length - side) / (side / 2)) + 1
    return sorted({round(k * (length - side) / (n - 1)) for k in range(n)})


def detect_one(pose, image, windows: bool):
    """(landmarks (33,4) normalised to ``image``, segmentation (H,W) float) of one person, or None:
    the whole image first; then, with ``windows``, square windows of each size in ``WINDOWS`` (the
    largest size that finds someone wins, and among its windows the detection with the highest mean
    landmark visibility), mapped back onto the image."""
    import numpy as np

    H, W = image.shape[:2]

    def run(img):
        result = pose.process(np.ascontiguousarray(img))
        if result.pose_landmarks is None:
            return None
        lm = np.array([[q.x, q.y, q.z, q.visibility] for q in result.pose_landmarks.landmark], np.float32)
        seg = result.segmentation_mask
        return lm, (np.zeros(img.shape[:2], np.float32) if seg is None else np.asarray(seg, np.float32))

    whole = run(image)
    if whole is not None or not windows:
        return whole
    for share in WINDOWS:
        side = max(16, int(round(share * min(H, W))))
        if share < 1.0 and side >= min(H, W):
            continue
        best = None
        for y in window_origins(H, side):
            for x in window_origins(W, side):
                got = run(image[y:y + side, x:x + side])
                if got is None:
                    continue
                lm, seg = got
                if best is not None and lm[:, 3].mean() <= best[0][:, 3].mean():
                    continue
                lm = lm.copy()
                lm[:, 0] = (lm[:, 0] * side + x) / W
                lm[:, 1] = (lm[:, 1] * side + y) / H
                lm[:, 2] = lm[:, 2] * side / W  # z is on the x scale
                full = np.zeros((H, W), np.float32)
                full[y:y + side, x:x + side] = seg
                best = (lm, full)
        if best is not None:
            return best
    return None


def find_people(images, args, mp, mp_pose) -> int:
    """Everyone in each image: detect one person, blank them out, detect again. Where the whole image
    shows nobody at all, the first search also tries square windows (``detect_one``)."""
    import numpy as np

    T, H, W = images.shape[:3]
    P = args.max_people
    count = np.zeros(T, np.int32)
    people = np.zeros((T, P, NUM_LANDMARKS, 4), np.float32)
    regions = np.zeros((T, P, H, W), np.uint8)
    with mp_pose.Pose(static_image_mode=True, model_complexity=args.model_complexity, enable_segmentation=True,
                      min_detection_confidence=args.min_detection_confidence) as pose:
        for i in range(T):
            report(args, "people", i, T)
            work = images[i].copy()
            fill = np.median(images[i].reshape(-1, 3), axis=0).astype(np.uint8)
            boxes = []
            for p in range(P):
                got = detect_one(pose, work, windows=p == 0)
                if got is None:
                    break
                lm, segmentation = got
                x0, y0, x1, y1 = _box(lm, W, H)
                if x1 - x0 < 4 or y1 - y0 < 4:
                    break
                dup = False
                for b in boxes:  # the same person again (blanking missed them): stop
                    ix = max(0, min(x1, b[2]) - max(x0, b[0])) * max(0, min(y1, b[3]) - max(y0, b[1]))
                    if ix > 0.5 * min((x1 - x0) * (y1 - y0), (b[2] - b[0]) * (b[3] - b[1])):
                        dup = True
                if dup:
                    break
                boxes.append((x0, y0, x1, y1))
                seg = segmentation > 0.5
                inside = np.zeros((H, W), bool)
                inside[y0:y1, x0:x1] = True
                region = seg & inside
                people[i, p] = lm
                regions[i, p] = region * 255
                count[i] = p + 1
                # blank the person (their segmentation inside their box, and the box's core)
                core = np.zeros((H, W), bool)
                cw = (x1 - x0) // 6
                core[y0:y1, x0 + cw:x1 - cw] = True
                work[region | (core & ~np.any(regions[i, :p] > 0, axis=0))] = fill
    report(args, "people", T, T)
    tmp = args.out + ".part.npz"
    np.savez(tmp, count=count, people=people, regions=regions, version=np.array(mp.__version__))
    os.replace(tmp, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
