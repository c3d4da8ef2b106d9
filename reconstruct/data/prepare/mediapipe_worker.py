"""Run mediapipe's legacy Pose solution over frames; a standalone script for the detector's interpreter.

    python mediapipe_worker.py IN.npz OUT.npz [--model-complexity 0|1]

IN.npz holds ``images`` (T,H,W,3) uint8 RGB. OUT.npz gets ``found`` (T,) bool, ``landmarks`` (T,33,4)
(x, y normalised to [0,1] by the image width/height, z relative depth, visibility), ``world``
(T,33,4) (metres, hip-centred, x right, y down, z away from the camera; visibility), ``masks``
(T,H,W) uint8 person segmentation (0..255) and ``version`` (the mediapipe version).

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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("inp")
    ap.add_argument("out")
    ap.add_argument("--model-complexity", type=int, default=1, choices=[0, 1],
                    help="0 lite, 1 full (both ship in the wheel; 2 'heavy' would be downloaded)")
    ap.add_argument("--min-detection-confidence", type=float, default=0.5)
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
            if result.pose_landmarks is None:
                continue
            found[i] = True
            landmarks[i] = [[p.x, p.y, p.z, p.visibility] for p in result.pose_landmarks.landmark]
            if result.pose_world_landmarks is not None:
                world[i] = [[p.x, p.y, p.z, p.visibility] for p in result.pose_world_landmarks.landmark]
            if result.segmentation_mask is not None:
                masks[i] = np.clip(result.segmentation_mask * 255.0 + 0.5, 0, 255).astype(np.uint8)
    tmp = args.out + ".part.npz"
    np.savez(tmp, found=found, landmarks=landmarks, world=world, masks=masks, version=np.array(mp.__version__))
    os.replace(tmp, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
