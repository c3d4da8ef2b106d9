"""Run mediapipe's legacy Pose solution over frames; a standalone script for the detector's interpreter.

    python mediapipe_worker.py IN.npz OUT.npz [--model-complexity 0|1] [--refine] [--mode pose|people]

IN.npz holds ``images`` (T,H,W,3) uint8 RGB. OUT.npz gets ``found`` (T,) bool, ``landmarks`` (T,33,4)
(x, y normalised to [0,1] by the image width/height, z relative depth, visibility), ``world``
(T,33,4) (metres, hip-centred, x right, y down, z away from the camera; visibility), ``masks``
(T,H,W) uint8 person segmentation (0..255) and ``version`` (the mediapipe version). Each hand the
pose found is looked at again by mediapipe's hand model in a square crop round it (``hand_crops.py``):
``hands`` (T,2,21,2) its 21 landmarks normalised like ``landmarks`` (the person's left hand first) and
``hands_found`` (T,2) bool (``--no-hands`` leaves both out).

``--refine`` also writes ``raw_masks`` and refines ``masks`` with GrabCut (``grabcut_refine.py``, OpenCV)
seeded by the segmentation and the landmarks; ``refine_used`` (T,) says where the refinement was kept.

``--mode people`` finds everyone in each image instead (the legacy Pose solution tracks one person):
detect, blank out the person found near their skeleton, detect again, up to ``--max-people``, then
look again at the faces nobody found holds (``search_people``); an image where the whole frame shows
nobody is searched again in square windows (``detect_one``). OUT.npz gets ``count`` (T,), ``people``
(T,P,33,4) normalised landmarks, ``regions`` (T,P,H,W) uint8 each person's segmentation, split
between people who touch by their skeletons (``skeleton_split.py``).

This file imports only numpy, mediapipe (``mediapipe==0.10.21``, the last release whose wheel ships
the pose, face and segmentation models) and its numpy-only siblings (``grabcut_refine.py`` also
needs OpenCV, ``skeleton_split.py``), so it can run in a separate virtualenv with ``numpy<2`` as that
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
    ap.add_argument("--no-hands", action="store_true", help="do not run the hand model on the pose's hands")
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
    if not args.no_hands:
        try:
            extra["hands"], extra["hands_found"] = detect_hands(images, landmarks, found, args)
        except ImportError as exc:  # an interpreter whose mediapipe lacks the hand model: no hands
            print(f"mediapipe's hand model cannot be imported ({exc!r}); the hands are not fitted", file=sys.stderr)
    if args.refine:
        _siblings_importable()
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
        extra.update(raw_masks=raw, refine_used=used)
    tmp = args.out + ".part.npz"
    np.savez(tmp, found=found, landmarks=landmarks, world=world, masks=masks, version=np.array(mp.__version__),
             **extra)
    os.replace(tmp, args.out)
    return 0


def detect_hands(images, landmarks, found, args):
    """(T,2,21,2) normalised hand landmarks and (T,2) bool found: mediapipe's hand model on a square
    crop round each of the pose's hands (``hand_crops.hand_box``) scaled to ``HAND_INPUT`` px, one hand
    per crop, each crop on its own (static images: a hand that moves out of a video's frame is not
    carried on)."""
    import numpy as np
    from mediapipe.python.solutions import hands as mp_hands

    _siblings_importable()
    from hand_crops import HAND_INPUT, HAND_POINTS, NUM_HAND_LANDMARKS, SIDES, crop_square, hand_box, uncrop

    try:
        import cv2

        def scale(img, size):
            grow = size > img.shape[0]
            return cv2.resize(img, (size, size), interpolation=cv2.INTER_CUBIC if grow else cv2.INTER_AREA)
    except ImportError:  # nearest neighbour, numpy only
        def scale(img, size):
            idx = (np.arange(size) * img.shape[0] / size).astype(int)
            return img[idx][:, idx]

    T, H, W = images.shape[:3]
    out = np.zeros((T, 2, NUM_HAND_LANDMARKS, 2), np.float32)
    hit = np.zeros((T, 2), bool)
    with mp_hands.Hands(static_image_mode=True, max_num_hands=1, model_complexity=1,
                        min_detection_confidence=args.min_detection_confidence) as hands:
        for i in range(T):
            report(args, "hands", i + 1, T)
            if not found[i]:
                continue
            for k, side in enumerate(SIDES):
                pts = landmarks[i, list(HAND_POINTS[side]), :2] * np.array([W, H], np.float32)
                box = hand_box(pts, H)
                crop = np.ascontiguousarray(scale(crop_square(images[i], box), HAND_INPUT))
                result = hands.process(crop)
                if not result.multi_hand_landmarks:
                    continue
                lm = np.array([[p.x, p.y] for p in result.multi_hand_landmarks[0].landmark], np.float64)
                out[i, k] = uncrop(lm, box) / np.array([W, H], np.float64)
                hit[i, k] = True
    return out, hit


def _siblings_importable() -> None:
    """This file's folder on ``sys.path`` (once): its numpy-only siblings import as top-level modules
    here, where the project's package cannot be imported."""
    here = os.path.dirname(os.path.abspath(__file__))
    if here not in sys.path:
        sys.path.insert(0, here)


def _seen_points(lm, W: int, H: int):
    """(n,2) pixels of a person's landmarks seen with visibility at least 0.3 ((33,4) normalised), or
    of all of them where fewer than 4 are."""
    import numpy as np

    seen = lm[:, 3] >= 0.3
    return lm[seen if seen.sum() >= 4 else slice(None), :2] * np.array([W, H])


def _box(lm, W: int, H: int) -> tuple[int, int, int, int]:
    """Pixel box (x0, y0, x1, y1) around a person's landmarks ((33,4) normalised), grown to cover the head
    and the feet."""
    pts = _seen_points(lm, W, H)
    x0, y0 = pts.min(0)
    x1, y1 = pts.max(0)
    h = max(y1 - y0, 1.0)
    return (int(max(0, x0 - 0.12 * h)), int(max(0, y0 - 0.2 * h)), int(min(W, x1 + 0.12 * h)),
            int(min(H, y1 + 0.08 * h)))


# the people search blanks a person's segmentation within this share of their stature (landmarks' height)
# of their bones, and everything within the smaller share: a coat's width round the skeleton, not
# the neighbour who touches it
BLANK_REACH = 0.12
CORE_REACH = 0.04
HEAD_REACH = 0.05  # and the face bones (nose, eyes, ears): a neighbour leaning close keeps her face


# a face nobody was found at is looked for in a square window this many face heights wide round it
FACE_WINDOW = 9.0


def _grown(box, share: float, W: int, H: int) -> tuple[slice, slice]:
    """Array slices of ``box`` (x0, y0, x1, y1) grown by ``share`` of its size each way, in the image."""
    x0, y0, x1, y1 = box
    gx, gy = share * (x1 - x0), share * (y1 - y0)
    return (slice(int(max(0, y0 - gy)), int(min(H, y1 + gy + 1))),
            slice(int(max(0, x0 - gx)), int(min(W, x1 + gx + 1))))


# a person found at a face nobody held whose torso's middle lies within this share of a found person's
# stature of theirs is that person again (their pose put the nose off their face)
SAME_TORSO = 0.08


def _overlap(a, b) -> float:
    """The area two boxes (x0, y0, x1, y1) share, as a share of the smaller one's."""
    ix = max(0, min(a[2], b[2]) - max(a[0], b[0])) * max(0, min(a[3], b[3]) - max(a[1], b[1]))
    return ix / max(min((a[2] - a[0]) * (a[3] - a[1]), (b[2] - b[0]) * (b[3] - b[1])), 1e-9)


def _torso(lm):
    """The middle of the shoulders and hips ((33,4) normalised landmarks), normalised."""
    return lm[[11, 12, 23, 24], :2].mean(0)


def _stature_px(lm, W: int, H: int) -> float:
    """A person's height in pixels from their seen landmarks ((33,4) normalised)."""
    import numpy as np

    pts = _seen_points(lm, W, H)
    return float(max(np.ptp(pts[:, 1]), np.ptp(pts[:, 0]), 1.0))


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


def _pose_in(pose, image):
    """(landmarks (33,4) normalised to ``image``, segmentation (H,W) float) of the person mediapipe's
    Pose finds in ``image``, or None."""
    import numpy as np

    result = pose.process(np.ascontiguousarray(image))
    if result.pose_landmarks is None:
        return None
    lm = np.array([[q.x, q.y, q.z, q.visibility] for q in result.pose_landmarks.landmark], np.float32)
    seg = result.segmentation_mask
    return lm, (np.zeros(image.shape[:2], np.float32) if seg is None else np.asarray(seg, np.float32))


def pose_in_window(pose, image, x: int, y: int, side: int):
    """``_pose_in`` on the square window of ``side`` pixels at (x, y) of ``image`` (clipped to it),
    mapped back onto the whole image; or None."""
    import numpy as np

    H, W = image.shape[:2]
    got = _pose_in(pose, image[y:y + side, x:x + side])
    if got is None:
        return None
    lm, seg = got
    h, w = seg.shape
    lm = lm.copy()
    lm[:, 0] = (lm[:, 0] * w + x) / W
    lm[:, 1] = (lm[:, 1] * h + y) / H
    lm[:, 2] = lm[:, 2] * w / W  # z is on the x scale
    full = np.zeros((H, W), np.float32)
    full[y:y + h, x:x + w] = seg
    return lm, full


def detect_one(pose, image, windows: bool):
    """(landmarks (33,4) normalised to ``image``, segmentation (H,W) float) of one person, or None:
    the whole image first; then, with ``windows``, square windows of each size in ``WINDOWS`` (the
    largest size that finds someone wins, and among its windows the detection with the highest mean
    landmark visibility), mapped back onto the image."""
    H, W = image.shape[:2]
    whole = _pose_in(pose, image)
    if whole is not None or not windows:
        return whole
    for share in WINDOWS:
        side = max(16, int(round(share * min(H, W))))
        if share < 1.0 and side >= min(H, W):
            continue
        best = None
        for y in window_origins(H, side):
            for x in window_origins(W, side):
                got = pose_in_window(pose, image, x, y, side)
                if got is not None and (best is None or got[0][:, 3].mean() > best[0][:, 3].mean()):
                    best = got
        if best is not None:
            return best
    return None


def find_faces(detector, image, W: int, H: int) -> list[tuple[float, float, float, float]]:
    """Pixel boxes (x0, y0, x1, y1) of the faces mediapipe's full-range face detector finds."""
    import numpy as np

    result = detector.process(np.ascontiguousarray(image))
    boxes = []
    for d in result.detections or []:
        b = d.location_data.relative_bounding_box
        boxes.append((b.xmin * W, b.ymin * H, (b.xmin + b.width) * W, (b.ymin + b.height) * H))
    return boxes


def face_of(lm, faces, W: int, H: int) -> int | None:
    """The index of the face box (grown by half its size each way) that holds the person's nose, or None."""
    x, y = float(lm[0, 0]) * W, float(lm[0, 1]) * H
    for j, (x0, y0, x1, y1) in enumerate(faces):
        gx, gy = 0.5 * (x1 - x0), 0.5 * (y1 - y0)
        if x0 - gx <= x <= x1 + gx and y0 - gy <= y <= y1 + gy:
            return j
    return None


def search_people(image, pose, face_finder, max_people: int):
    """Everyone in ``image`` (H,W,3) uint8: (landmarks (n,33,4) normalised, regions (n,H,W) bool), left
    unsorted. ``pose`` and ``face_finder`` are mediapipe's Pose and FaceDetection (anything with their
    ``process``).

    Detect one person, blank them out near their own skeleton, detect again. Where the whole image
    shows nobody at all, the first search also tries square windows (``detect_one``). Then each face
    that nobody found holds (found on the image with everyone found blanked out) is looked for again
    with the other such faces hidden: the pose detector starts from a face, and between two people
    who lean together it found one skeleton for both. At the end every pixel of anyone's
    segmentation goes to the person whose skeleton is nearest (``skeleton_split``): a segmentation
    takes in whoever touches its person."""
    import numpy as np

    _siblings_importable()
    from skeleton_split import distance_to_segments, skeleton_segments, split_by_skeleton

    H, W = image.shape[:2]
    work = image.copy()
    fill = np.median(image.reshape(-1, 3), axis=0).astype(np.uint8)
    boxes, marks, regions, dists = [], [], [], []

    def add(lm, segmentation, new: bool = False) -> bool:
        """Keep a detection unless it is someone already found (a box mostly inside one found before;
        ``new``, found at a face nobody held: a torso where one found before has theirs); blank them
        in ``work``."""
        x0, y0, x1, y1 = _box(lm, W, H)
        if x1 - x0 < 4 or y1 - y0 < 4:
            return False
        # the same person again (blanking missed them). People who lean together share most of a
        # box: found at a face nobody held, the same torso is the same person
        if new and any(np.hypot(*((_torso(lm) - _torso(other)) * [W, H])) < SAME_TORSO * _stature_px(other, W, H)
                       for other in marks):
            return False
        if not new and any(_overlap(b, (x0, y0, x1, y1)) > 0.5 for b in boxes):
            return False
        boxes.append((x0, y0, x1, y1))
        inside = np.zeros((H, W), bool)
        inside[y0:y1, x0:x1] = True
        region = (segmentation > 0.5) & inside
        marks.append(lm)
        regions.append(region)
        segs, head = skeleton_segments(lm[:, :2] * np.array([W, H], np.float32), lm[:, 3])
        body_dist = distance_to_segments(segs[~head], H, W)
        head_dist = distance_to_segments(segs[head], H, W)
        dist = np.minimum(body_dist, head_dist)
        dists.append(dist)
        # blank the person: their segmentation near their bones, and their bones' core whatever the
        # segmentation says (a neighbour further off is left for the next detection)
        reach = _stature_px(lm, W, H)
        near = (body_dist < BLANK_REACH * reach) | (head_dist < HEAD_REACH * reach)
        work[(region & near) | (dist < CORE_REACH * reach)] = fill
        return True

    while len(boxes) < max_people:
        got = detect_one(pose, work, windows=not boxes)
        if got is None or not add(*got):
            break
    faces = find_faces(face_finder, work, W, H)
    held = {face_of(lm, faces, W, H) for lm in marks}
    left = sorted((j for j in range(len(faces)) if j not in held),
                  key=lambda j: -(faces[j][2] - faces[j][0]) * (faces[j][3] - faces[j][1]))
    for j in left:
        if len(boxes) >= max_people:
            break
        view = work.copy()
        for k in left:  # the other faces nobody holds yet out of sight
            if k != j:
                view[_grown(faces[k], 0.3, W, H)] = fill
        fx0, fy0, fx1, fy1 = faces[j]
        side = int(min(H, W, max(16, FACE_WINDOW * (fy1 - fy0))))
        x = int(np.clip(0.5 * (fx0 + fx1) - side / 2, 0, W - side))
        y = int(np.clip(fy0 - 0.5 * (fy1 - fy0), 0, H - side))
        for look in (lambda: _pose_in(pose, view), lambda: pose_in_window(pose, view, x, y, side)):
            got = look()  # the window is run only when the whole image did not find them
            if got is not None and face_of(got[0], faces, W, H) == j and add(*got, new=True):
                break
    if not boxes:
        return np.zeros((0, NUM_LANDMARKS, 4), np.float32), np.zeros((0, H, W), bool)
    return np.stack(marks), split_by_skeleton(np.stack(regions), np.stack(dists))


def find_people(images, args, mp, mp_pose) -> int:
    """``search_people`` on each image, with mediapipe's Pose and its full-range face detector."""
    import numpy as np
    from mediapipe.python.solutions import face_detection

    T, H, W = images.shape[:3]
    P = args.max_people
    count = np.zeros(T, np.int32)
    people = np.zeros((T, P, NUM_LANDMARKS, 4), np.float32)
    regions = np.zeros((T, P, H, W), np.uint8)
    with mp_pose.Pose(static_image_mode=True, model_complexity=args.model_complexity, enable_segmentation=True,
                      min_detection_confidence=args.min_detection_confidence) as pose, \
            face_detection.FaceDetection(model_selection=1, min_detection_confidence=0.5) as face_finder:
        for i in range(T):
            report(args, "people", i, T)
            marks, found = search_people(images[i], pose, face_finder, P)
            count[i] = len(marks)
            people[i, :len(marks)] = marks
            regions[i, :len(marks)] = found * 255
    report(args, "people", T, T)
    tmp = args.out + ".part.npz"
    np.savez(tmp, count=count, people=people, regions=regions, version=np.array(mp.__version__))
    os.replace(tmp, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
