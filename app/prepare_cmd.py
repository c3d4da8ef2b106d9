"""``wonderhuman-studio prepare INPUT --out SCENE``: a video, an image or a folder of images -> a scene
folder (see docs/prepare.md)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_prepare_parser(sub) -> None:
    s = sub.add_parser("prepare", help="make a scene folder from a video, an image or a folder of images: frames, "
                                       "person masks, mediapipe keypoints, fitted body shape, poses and camera")
    s.add_argument("video", type=Path, metavar="INPUT",
                   help="video file (.mp4, .mov, ...), image (.jpg, .png, .webp, ...) or folder of images "
                        "(in name order, numbers by value: frame2 before frame10)")
    s.add_argument("--out", required=True, type=Path, help="scene folder to write (replaced if it is one)")
    s.add_argument("--size", type=int, default=512,
                   help="longer side of the scene's frames in pixels (default 512; a person crop smaller than this "
                        "is kept at its own size)")
    s.add_argument("--every", type=int, default=1, help="use every N-th frame (or image)")
    s.add_argument("--max-frames", type=int, default=None, help="use at most this many frames")
    s.add_argument("--person", type=int, default=None, metavar="N",
                   help="which person to prepare when several are in view, numbered 1, 2, ... from left to right "
                        "(default: the largest and most central)")
    s.add_argument("--no-crop", action="store_true", help="keep the whole frame instead of cropping around the person")
    s.add_argument("--masks", metavar="PATH",
                   help="your own person masks instead of the segmenter's: a mask video, a mask image (for a photo) "
                        "or a folder of mask images (named as the frames' images, or one per frame in order); "
                        "white or opaque: person; or a scene folder prepare wrote from this input, its frames/mask "
                        "fixed (docs/prepare.md)")
    s.add_argument("--no-alpha", action="store_true",
                   help="segment a cut-out (an image or a video with transparency) instead of taking its alpha as the mask")
    s.add_argument("--no-refine", action="store_true", help="keep the segmenter's mask (no GrabCut refinement)")
    s.add_argument("--no-fill-holes", action="store_true", help="keep small enclosed holes in the mask")
    s.add_argument("--no-turn", action="store_true",
                   help="keep the frames as stored even when the person lies on their side or stands upside down "
                        "in them (by default they are read turned so that the person stands)")
    s.add_argument("--height", type=float, default=None, metavar="METRES",
                   help="the person's height: fixes the body size one camera cannot tell (default: a population prior)")
    s.add_argument("--no-shape", action="store_true", help="keep the default body shape (fit poses only)")
    s.add_argument("--upright", choices=["auto", "on", "off"], default="auto",
                   help="prior that keeps a standing body upright with the legs under the hips where one view cannot "
                        "tell depth: auto (when the person barely turns or moves), on, off")
    s.add_argument("--fov", type=float, default=50.0, help="vertical field-of-view guess in degrees of the whole "
                                                           "frame (refined)")
    s.add_argument("--fixed-focal", action="store_true", help="keep the focal length of --fov")
    s.add_argument("--iters", type=int, default=None, help="keypoint-fit iterations")
    s.add_argument("--silhouette-iters", type=int, default=None, help="silhouette-fit iterations (0: off)")
    s.add_argument("--detector-python", default=None, metavar="PATH",
                   help="Python interpreter with mediapipe==0.10.21 (default: $WONDERHUMAN_DETECTOR_PYTHON, this "
                        "interpreter if it has mediapipe, else .venv-video/bin/python)")
    s.add_argument("--model-complexity", type=int, default=1, choices=[0, 1], help="mediapipe pose model: 0 lite, 1 full")
    s.add_argument("--no-report-image", action="store_true", help="do not draw SCENE/prepare_report.png")
    s.add_argument("--json", action="store_true", help="print the report as JSON instead of a table")
    s.set_defaults(func=run_prepare)


class StageBars:
    """``prepare``'s progress on the command line: a tqdm bar per step (finding people, detecting
    poses, refining masks, fitting to keypoints, to the silhouette), on stderr."""

    def __init__(self) -> None:
        self.stage, self.bar = None, None

    def __call__(self, stage: str, done: int, total: int) -> None:
        from tqdm import tqdm

        from reconstruct.data.prepare.pipeline import STAGE_WORDS

        if stage != self.stage or self.bar is None:
            self.close()
            unit = "step" if stage in ("keypoints", "silhouette") else "frame"
            self.stage, self.bar = stage, tqdm(total=total, desc=STAGE_WORDS.get(stage, stage), unit=unit,
                                               leave=True)
        self.bar.update(max(0, done - self.bar.n))
        if done >= total:
            self.close()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.update(max(0, self.bar.total - self.bar.n) if self.stage in ("keypoints", "silhouette") else 0)
            self.bar.close()
        self.stage, self.bar = None, None


def run_prepare(args: argparse.Namespace) -> int:
    import json

    from reconstruct.data.prepare import FitConfig, MediapipeDetector, format_report, prepare_video
    from reconstruct.data.prepare.inputs import probe_input
    from reconstruct.data.prepare.pipeline import check_output_folder

    if args.size < 64:
        raise ValueError(f"--size must be at least 64, found {args.size}")
    if args.person is not None and args.person < 1:
        raise ValueError(f"--person counts from 1 (left to right), found {args.person}")
    if args.height is not None and not 0.5 <= args.height <= 2.5:
        raise ValueError(f"--height is the person's height in metres (0.5 to 2.5), found {args.height}")
    check_output_folder(args.out)
    probe_input(args.video)  # a missing or unreadable input is reported before anything else runs
    if args.masks is not None and not Path(args.masks).exists():
        raise FileNotFoundError(f"{args.masks}: no such mask video, image or folder (--masks names your own person "
                                f"masks: a mask video, a mask image or a folder of mask images)")
    kw = {"fov_y_deg": args.fov, "refine_focal": not args.fixed_focal, "fit_shape": not args.no_shape,
          "stature_m": args.height, "upright": args.upright}
    if args.iters is not None:
        kw["keypoint_iters"] = args.iters
    if args.silhouette_iters is not None:
        kw["silhouette_iters"] = args.silhouette_iters
    detector = MediapipeDetector(args.detector_python, model_complexity=args.model_complexity,
                                 refine=not args.no_refine)
    detector.resolve()  # a missing detector is reported before the input is read
    bars = StageBars()
    try:
        out, report = prepare_video(args.video, args.out, detector=detector, fit_config=FitConfig(**kw),
                                    max_size=args.size, every=args.every, max_frames=args.max_frames,
                                    person=args.person, crop=not args.no_crop, fill_holes=not args.no_fill_holes,
                                    turn=not args.no_turn, report_image=not args.no_report_image,
                                    masks=args.masks, use_alpha=not args.no_alpha, progress=bars)
    finally:
        bars.close()
    print(json.dumps(report, indent=1) if args.json else format_report(report))
    print(f"wrote {out}")
    return 0
