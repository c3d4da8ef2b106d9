"""``wonderhuman-studio`` command line: the studio window (later), and headless subcommands."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from reconstruct.data.load import DEFAULT_SCENE


def _cmd_synth(args) -> int:
    from reconstruct.data.load import load_synthetic
    from reconstruct.data.scene_io import write_scene
    from reconstruct.data.synthetic.generator import SyntheticConfig

    config = SyntheticConfig(seed=args.seed, num_frames=args.frames, image_size=args.size)
    scene = load_synthetic(config, use_cache=not args.no_cache)
    write_scene(scene, args.out)
    print(scene.summary())
    print(f"wrote {args.out}")
    return 0


def _cmd_scene_info(args) -> int:
    from reconstruct.data.load import load_scene

    print(load_scene(args.scene).summary())
    return 0


def _cmd_contact_sheet(args) -> int:
    from app.contact_sheet import write_contact_sheet
    from reconstruct.data.load import load_scene

    scene = load_scene(args.scene)
    print(f"wrote {write_contact_sheet(scene, args.out, frame_index=args.frame)}")
    return 0


def _cmd_demo(args) -> int:
    from app.demo import run_demo

    return run_demo(args.scene, Path(args.out), threads=args.threads)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="wonderhuman-studio",
                                description="Animatable 3D Gaussian avatars from monocular front-view video.")
    sub = p.add_subparsers(dest="command")

    s = sub.add_parser("synth", help="write a synthetic scene folder (body, clothing, motion, cameras, ground truth)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True, type=Path)
    s.add_argument("--frames", type=int, default=60)
    s.add_argument("--size", type=int, default=512, help="image width and height in pixels")
    s.add_argument("--no-cache", action="store_true", help="build from scratch instead of reusing the scene cache")
    s.set_defaults(func=_cmd_synth)

    s = sub.add_parser("scene-info", help="load a scene and print what it holds")
    s.add_argument("scene", nargs="?", default=DEFAULT_SCENE, help="scene folder or synthetic:seed=S")
    s.set_defaults(func=_cmd_scene_info)

    s = sub.add_parser("contact-sheet", help="PNG of the training view and every evaluation view")
    s.add_argument("scene", nargs="?", default=DEFAULT_SCENE)
    s.add_argument("--out", required=True, type=Path)
    s.add_argument("--frame", type=int, default=None)
    s.set_defaults(func=_cmd_contact_sheet)

    s = sub.add_parser("demo", help="the headless pipeline on the built-in demo scene")
    s.add_argument("--scene", default=DEFAULT_SCENE)
    s.add_argument("--out", default="runs/demo", type=Path)
    s.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    s.set_defaults(func=_cmd_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, RuntimeError) as exc:
        print(f"wonderhuman-studio {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
