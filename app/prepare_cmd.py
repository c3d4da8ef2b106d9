"""``wonderhuman-studio prepare VIDEO --out SCENE``: a raw video -> a scene folder (see docs/prepare.md)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_prepare_parser(sub) -> None:
    s = sub.add_parser("prepare", help="make a scene folder from a raw video (mp4/mov): frames, person masks, "
                                       "mediapipe keypoints, fitted body poses and camera")
    s.add_argument("video", type=Path, help="video file (.mp4, .mov, ...)")
    s.add_argument("--out", required=True, type=Path, help="scene folder to write (replaced if it is one)")
    s.add_argument("--size", type=int, default=512, help="longer side of the scene's frames in pixels (default 512)")
    s.add_argument("--every", type=int, default=1, help="use every N-th frame of the video")
    s.add_argument("--max-frames", type=int, default=None, help="use at most this many frames")
    s.add_argument("--fov", type=float, default=50.0, help="vertical field-of-view guess in degrees (refined)")
    s.add_argument("--fixed-focal", action="store_true", help="keep the focal length of --fov")
    s.add_argument("--iters", type=int, default=None, help="keypoint-fit iterations")
    s.add_argument("--silhouette-iters", type=int, default=None, help="silhouette-fit iterations (0: off)")
    s.add_argument("--detector-python", default=None, metavar="PATH",
                   help="Python interpreter with mediapipe==0.10.21 (default: $WONDERHUMAN_DETECTOR_PYTHON, this "
                        "interpreter if it has mediapipe, else .venv-video/bin/python)")
    s.add_argument("--model-complexity", type=int, default=1, choices=[0, 1], help="mediapipe pose model: 0 lite, 1 full")
    s.add_argument("--json", action="store_true", help="print the report as JSON instead of a table")
    s.set_defaults(func=run_prepare)


def run_prepare(args: argparse.Namespace) -> int:
    import json

    from reconstruct.data.prepare import FitConfig, MediapipeDetector, format_report, prepare_video
    from reconstruct.data.prepare.pipeline import check_output_folder
    from reconstruct.data.prepare.video import probe_video

    if args.size < 64:
        raise ValueError(f"--size must be at least 64, found {args.size}")
    check_output_folder(args.out)
    probe_video(args.video)  # a missing or unreadable video is reported before anything else runs
    kw = {"fov_y_deg": args.fov, "refine_focal": not args.fixed_focal}
    if args.iters is not None:
        kw["keypoint_iters"] = args.iters
    if args.silhouette_iters is not None:
        kw["silhouette_iters"] = args.silhouette_iters
    detector = MediapipeDetector(args.detector_python, model_complexity=args.model_complexity)
    detector.resolve()  # a missing detector is reported before the video is read
    out, report = prepare_video(args.video, args.out, detector=detector, fit_config=FitConfig(**kw),
                                max_size=args.size, every=args.every, max_frames=args.max_frames)
    print(json.dumps(report, indent=1) if args.json else format_report(report))
    print(f"wrote {out}")
    return 0
