"""``wonderhuman-studio`` command line: the studio window (no subcommand), and headless subcommands."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from reconstruct.data.load import DEFAULT_SCENE
from reconstruct.gaussian_files import FORMATS as SPLAT_FORMATS


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

    return run_demo(args.scene, Path(args.out), minutes=args.minutes, stage2_minutes=args.stage2_minutes,
                    threads=args.threads, device=args.device)


def _stage1_config(args):
    """Stage I settings: the flags, then ``--set KEY=VALUE`` (converted by each field's type;
    nested avatar settings as ``avatar.KEY``). The dataclass checks the values."""
    from reconstruct import config as config_layer
    from reconstruct.train.config import Stage1Config

    kw: dict = {"seed": args.seed}
    if args.device:
        kw["device"] = args.device
    avatar = {k: v for k, v in (("gaussian_resolution", args.gaussian_res), ("hidden", args.hidden)) if v}
    if avatar:
        kw["avatar"] = avatar
    for key in ("iters", "minutes", "threads"):
        if getattr(args, key) is not None:
            kw[key] = getattr(args, key)
    if args.eval_every is not None:
        kw["eval_every_seconds"] = args.eval_every
    if args.pose_refinement:
        kw["pose_refinement"] = True
    if args.holdout is not None:
        kw["holdout"] = args.holdout
    if args.lpips_backbone or args.lpips_lin:
        kw.update(lpips_backbone=args.lpips_backbone, lpips_lin=args.lpips_lin, lpips_net=args.lpips_net)
    sets = config_layer.parse_overrides(Stage1Config, args.set, "Stage I", "--set")
    if "avatar" in sets:
        kw["avatar"] = {**kw.get("avatar", {}), **sets.pop("avatar")}
    kw.update(sets)
    return config_layer.with_overrides(Stage1Config(), kw)


def _cmd_train(args) -> int:
    from app.train_cmd import train

    train(args.scene, args.out, _stage1_config(args), progress=not args.quiet, stage=args.stage,
          stage2=_stage2_overrides(args), allow_incomplete=args.allow_incomplete, device=args.device)
    return 0


STAGE2_FLAGS = {  # command-line flag -> Stage2Config field
    "stage2_iters": "iters", "stage2_minutes": "minutes", "prior": "prior", "prior_path": "prior_path",
    "canonical_ratio": "canonical_ratio", "given_ratio": "given_view_ratio", "lambda_sds": "lambda_sds",
    "sds_t0": "sds_t0", "sds_k": "sds_k", "epoch_steps": "epoch_steps",
    "visibility_threshold": "visibility_threshold", "lambda_p": "lambda_pose_features",
}
STAGE2_SWITCHES = {"no_pose_injection": "pose_injection", "no_canonical_sds": "canonical_sds",
                   "no_observation_sds": "observation_sds", "no_view_selection": "view_selection",
                   "no_progressive": "progressive", "no_unseen_normals": "unseen_normals"}


def _stage2_overrides(args) -> dict:
    """The Stage II settings given on the command line: the flags, then ``--set2 KEY=VALUE``
    (converted by each field's type); checked by Stage2Config at once."""
    from reconstruct import config as config_layer
    from reconstruct.stage2.config import Stage2Config

    out = {field: getattr(args, flag) for flag, field in STAGE2_FLAGS.items() if getattr(args, flag) is not None}
    out.update({field: False for flag, field in STAGE2_SWITCHES.items() if getattr(args, flag)})
    out.update(config_layer.parse_overrides(Stage2Config, args.set2, "Stage II", "--set2"))
    config_layer.with_overrides(Stage2Config(), out)  # fail early on bad values
    return out


def _cmd_eval(args) -> int:
    from app.train_cmd import evaluate

    return evaluate(args.run, as_json=args.json, scale=args.scale, novel=args.novel,
                    novel_frames=args.novel_frames)


def _export_what(args) -> str:
    """Which export the flags ask for: orbit, poses, novel, motion, canonical or frame (.ply only);
    mistakes are argparse usage errors (exit status 2, nothing read or written)."""
    parser = args.export_parser
    if (args.out is None) == (args.ply is None):
        parser.error("give one of --out FILE.mp4|.gif (a video) and --ply OUT (the Gaussians as .ply)")
    chosen = [k for k in ("orbit", "poses", "novel", "motion") if getattr(args, k) is not None]
    chosen += ["canonical"] if args.canonical else []
    if args.ply is None:
        if not chosen:
            parser.error("a video needs one of --orbit N, --poses SCENE, --novel NAME, --motion FILE")
        if args.canonical:
            parser.error("--canonical is for --ply (the canonical-space Gaussians); for a video use --orbit")
        return chosen[0]
    if args.orbit is not None:
        parser.error("--orbit makes a video (--out); a .ply holds one pose (--frame, --canonical) or a sequence "
                     "(--poses, --novel, --motion)")
    if chosen and args.frame is not None:
        parser.error(f"--frame picks the pose of a single .ply; it cannot go with --{chosen[0]}")
    return chosen[0] if chosen else "frame"


def _cmd_export(args) -> int:
    from app.export import (
        VIDEO_SUFFIXES,
        check_destination,
        check_motion_times,
        check_ply_destination,
        check_splat_format,
        export_novel,
        export_orbit,
        export_poses,
        motion_poses,
        plan_motion,
        plan_ply,
        read_motion,
        render_plan,
        write_ply_plan,
    )
    from reconstruct.data.load import load_scene
    from reconstruct.run_folder import RunFolder

    what = _export_what(args)
    run = RunFolder(args.run)
    run.check("export")
    if args.orbit is not None and args.orbit < 1:
        raise ValueError(f"--orbit must be at least 1, found {args.orbit}")
    if args.novel is not None:
        from reconstruct.body.novel_poses import NOVEL_POSES

        if args.novel not in NOVEL_POSES:
            raise ValueError(f"--novel {args.novel!r}: choose one of {', '.join(NOVEL_POSES)}")
        if args.frames < 2:
            raise ValueError(f"--frames must be at least 2, found {args.frames}")
    if what != "motion" and (args.start is not None or args.end is not None or args.loop):
        raise ValueError("--start, --end and --loop apply to --motion only")
    if args.fps is not None and args.fps <= 0:
        raise ValueError(f"--fps must be positive, found {args.fps}")
    # before any loading or rendering: the destination, then the motion file
    if args.ply is not None:
        sequence = what not in ("frame", "canonical")
        check_ply_destination(args.ply, sequence=sequence, overwrite=args.overwrite)
        check_splat_format(args.ply, args.format, sequence=sequence)
    elif args.format is not None:
        raise ValueError("--format applies to --ply only")
    else:
        check_destination(args.out, suffixes=VIDEO_SUFFIXES)
    clip = None
    if what == "motion":
        check_motion_times(args.start, args.end)
        clip = read_motion(args.motion)
    avatar = run.resume().avatar()
    scene = avatar.scene
    progress = not args.quiet
    motion = None
    if clip is not None:
        import time

        t0 = time.perf_counter()
        motion = motion_poses(avatar, clip, fps=args.fps, start=args.start, end=args.end, loop=args.loop)
        print(f"{args.motion}: {clip.num_frames} frames at {clip.fps:g} fps -> {len(motion)} frames at "
              f"{motion.fps:g} fps on the avatar's body (retargeted in {time.perf_counter() - t0:.2f} s)")
        for note in motion.notes:
            print(f"  - {note}")
    poses = None
    if what == "poses":
        poses = load_scene(args.poses, progress=False)
        if poses.name == scene.name:
            poses = scene  # the run's own scene: use the avatar's (possibly refined) poses
    if args.ply is not None:
        plan = plan_ply(avatar, args.ply, frame=args.frame if what == "frame" else None,
                        canonical=what == "canonical", novel=args.novel, frames=args.frames, motion=motion,
                        scene=poses, overwrite=args.overwrite)
        out = write_ply_plan(plan, up=args.up, sh_degree=args.sh_degree, progress=progress, overwrite=args.overwrite,
                             fmt=args.format)
        count = f" ({len(plan)} frames, frame_0000.{args.format or 'ply'} ...)" if plan.sequence else ""
        print(f"wrote {out}{count}")
        return 0
    common = {"mode": args.mode, "progress": progress}
    if what == "orbit":
        fps = 30 if args.fps is None else args.fps
        out = export_orbit(avatar, args.out, frames=args.orbit, size=args.size, fps=fps,
                           frame_index=args.frame or 0, **common)
    elif what == "novel":
        out = export_novel(avatar, args.out, args.novel, frames=args.frames, size=args.size, fps=args.fps, **common)
    elif what == "motion":
        out = render_plan(plan_motion(avatar, args.out, motion, size=args.size), **common)
    else:
        out = export_poses(avatar, args.out, scene=poses, size=args.size, fps=args.fps, **common)
    print(f"wrote {out}")
    return 0


def _cmd_migrate(args) -> int:
    from app.train_cmd import migrate

    return migrate(args.run, trust=args.trust)


def _cmd_studio(args) -> int:
    from app.studio.window import NO_DISPLAY_MESSAGE, NoDisplayError, display_available

    if args.studio_ply is not None and (args.studio_run is not None or args.studio_scene is not None
                                        or args.studio_device is not None):
        raise ValueError("--ply opens the .ply viewer (no training); it cannot go with --scene, --run or --device")
    if not display_available():
        print(NO_DISPLAY_MESSAGE)
        return 1
    try:
        if args.studio_ply is not None:
            from app.studio.viewer import run_viewer

            return run_viewer(args.studio_ply)
        from app.studio.window import run_studio

        return run_studio(args.studio_scene or DEFAULT_SCENE, args.studio_run, device=args.studio_device)
    except NoDisplayError:
        print(NO_DISPLAY_MESSAGE)
        return 1


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="wonderhuman-studio",
                                description="Animatable 3D Gaussian avatars from monocular front-view video. "
                                            "With no subcommand: the interactive studio window.")
    p.add_argument("--scene", dest="studio_scene", metavar="SCENE", default=None,
                   help=f"studio: scene folder or synthetic:seed=S to train on (default {DEFAULT_SCENE})")
    p.add_argument("--run", dest="studio_run", metavar="RUN", type=Path, default=None,
                   help="studio: run folder (resumes its checkpoint; saved to on exit)")
    p.add_argument("--device", dest="studio_device", choices=["cpu", "cuda"], default=None,
                   help="studio: where to train (default: a resumed run's own device, else cpu)")
    p.add_argument("--ply", dest="studio_ply", metavar="FILE", type=Path, default=None,
                   help="studio: view Gaussians without training: a 3DGS .ply (ours or any other program's), "
                        "SuperSplat's .compressed.ply, a .splat, a .spz or a .sog")
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

    s = sub.add_parser("train", help="train an avatar on a scene (resumes when RUN has a checkpoint)")
    s.add_argument("--scene", default=DEFAULT_SCENE, help="scene folder or synthetic:seed=S")
    s.add_argument("--out", required=True, type=Path, help="run folder")
    s.add_argument("--stage", default="1", choices=["1", "2", "all"])
    s.add_argument("--iters", type=int, default=None)
    s.add_argument("--minutes", type=float, default=None, help="wall-clock budget (whichever of iters/minutes ends first)")
    s.add_argument("--device", default=None, choices=["cpu", "cuda"],
                   help="where to train (default: the run's own device when resuming, else cpu; a run trained "
                        "on CUDA continues on the CPU where there is none)")
    s.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--gaussian-res", type=int, default=None, help="positional UV map resolution (one Gaussian per texel)")
    s.add_argument("--hidden", type=int, default=None, help="decoder width")
    s.add_argument("--eval-every", type=float, default=None, help="seconds of training between evaluations")
    s.add_argument("--pose-refinement", action="store_true",
                   help="optimise per-frame poses on any scene (scenes prepare made from a video or a folder of "
                        "frames refine them by default; --set pose_refinement_prepared=false keeps them as fitted)")
    s.add_argument("--holdout", type=int, default=None, metavar="K",
                   help="hold every K-th frame out of training for seen-view validation (default 8 for a scene "
                        "without evaluation views, e.g. your own video; 0 = off)")
    s.add_argument("--lpips-backbone", default=None, help="AlexNet/VGG backbone weights (torchvision state dict)")
    s.add_argument("--lpips-lin", default=None, help="LPIPS linear-layer weights (alex.pth / vgg.pth)")
    s.add_argument("--lpips-net", default="alex", choices=["alex", "vgg"])
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="override any Stage I setting")
    g = s.add_argument_group("Stage II (--stage 2 continues the run's Stage I; --stage all runs both)")
    g.add_argument("--stage2-iters", type=int, default=None, help="Stage II steps (default 1500)")
    g.add_argument("--stage2-minutes", type=float, default=None, help="Stage II wall-clock budget")
    g.add_argument("--prior", default=None, choices=["builtin", "zero123"],
                   help="guidance for unseen views: the built-in propagated-appearance prior, or Zero123 SDS")
    g.add_argument("--prior-path", default=None, help="diffusers-format Zero123 / Stable Zero123 folder")
    g.add_argument("--canonical-ratio", type=float, default=None, help="share of guidance steps in canonical space (0.5)")
    g.add_argument("--given-ratio", type=float, default=None, help="share of steps that are given-view steps (0.5)")
    g.add_argument("--lambda-sds", type=float, default=None, help="λ_SDS,0 (0.3)")
    g.add_argument("--sds-t0", type=float, default=None, help="epoch from which λ_SDS halves (100)")
    g.add_argument("--sds-k", type=float, default=None, help="epochs between halvings (100)")
    g.add_argument("--epoch-steps", type=float, default=None, help="steps per schedule epoch (2)")
    g.add_argument("--visibility-threshold", type=float, default=None, help="unseen when visible share <= this (0.5)")
    g.add_argument("--lambda-p", type=float, default=None, help="λ_p, pose-feature regulariser (0.5)")
    for flag in STAGE2_SWITCHES:
        g.add_argument("--" + flag.replace("_", "-"), action="store_true", help="ablation: turn this part off")
    g.add_argument("--set2", action="append", metavar="KEY=VALUE", help="override any Stage II setting")
    g.add_argument("--allow-incomplete", action="store_true", help="start Stage II on an unfinished Stage I run")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_cmd_train)

    s = sub.add_parser("eval", help="evaluate a run on its scene's held-out views; writes RUN/error_vs_time.png")
    s.add_argument("run", type=Path)
    s.add_argument("--json", action="store_true")
    s.add_argument("--scale", type=int, default=1,
                   help="render every view at this multiple of the scene's resolution (holes show at zoom); "
                        "adds hole fraction and alpha IoU at that scale")
    s.add_argument("--novel", metavar="NAME", choices=("walk", "arms_up"), default=None,
                   help="also score coverage in a novel pose sequence (walk or arms_up) against the ground truth "
                        "of a synthetic scene: holes and alpha IoU from the front, both sides and the back")
    s.add_argument("--novel-frames", type=int, default=8, help="poses of the --novel sequence (default 8)")
    s.set_defaults(func=_cmd_eval)

    s = sub.add_parser("export", help="render a trained avatar as a video (.mp4/.gif: 360° orbit, a scene's poses, a "
                                      "novel sequence or a motion file) or write its Gaussians as 3DGS .ply")
    s.add_argument("run", type=Path)
    what = s.add_mutually_exclusive_group()
    what.add_argument("--orbit", type=int, metavar="N", help="a full orbit of N frames around the avatar (video)")
    what.add_argument("--poses", metavar="SCENE", help="one frame per pose of SCENE (folder or synthetic:...), "
                                                       "seen from its training camera")
    what.add_argument("--novel", metavar="NAME", help="a novel pose sequence: walk (a walk cycle) or arms_up, "
                                                      "seen from the video's first training camera")
    what.add_argument("--motion", metavar="FILE", type=Path,
                      help="a motion file (.bvh, .fbx, .glb/.gltf, SMPL/SMPL-H/SMPL-X .npz) retargeted onto the "
                           "avatar, starting where the video's first frame stands (docs/motion.md)")
    what.add_argument("--canonical", action="store_true", help="--ply: the Gaussians in the canonical space")
    out = s.add_argument_group("output (one of)")
    out.add_argument("--out", type=Path, default=None, help="video file (.mp4 or .gif)")
    out.add_argument("--ply", type=Path, default=None, metavar="OUT",
                     help="Gaussians: OUT.ply (3DGS), OUT.compressed.ply, OUT.splat, OUT.spz or OUT.sog for one "
                          "pose (--frame F, default 0, or --canonical); a new folder for a sequence (--poses, "
                          "--novel, --motion): OUT/frame_0000.ply ... (--format for the others; docs/ply.md)")
    s.add_argument("--size", type=int, default=512, help="frame size in pixels (longer side for --poses)")
    s.add_argument("--fps", type=float, default=None,
                   help="frames per second (default 30 for --orbit, the scene's otherwise; --motion is resampled to it)")
    s.add_argument("--frame", type=int, default=None, help="pose (frame index) the orbit or the single .ply shows (0)")
    s.add_argument("--frames", type=int, default=30, help="frames of a --novel sequence")
    s.add_argument("--mode", default="rgb", choices=["rgb", "normal", "depth", "alpha", "visibility"])
    m = s.add_argument_group("--motion")
    m.add_argument("--start", type=float, default=None, help="seconds into the motion file to start at")
    m.add_argument("--end", type=float, default=None, help="seconds into the motion file to end at")
    m.add_argument("--loop", action="store_true", help="make the motion loop seamlessly (in place)")
    p_ = s.add_argument_group("--ply")
    p_.add_argument("--up", default="y_down", choices=["y_down", "z_up"],
                    help="y_down: the 3DGS/COLMAP convention splat viewers expect (default); z_up: ours")
    p_.add_argument("--sh-degree", type=int, default=3, choices=[0, 1, 2, 3],
                    help="SH degree of the file (higher coefficients are zero; 3 is what viewers expect)")
    p_.add_argument("--overwrite", action="store_true", help="replace an existing sequence folder")
    p_.add_argument("--format", default=None, choices=SPLAT_FORMATS,
                    help="layout of a sequence's files (default ply; .spz is about 20 times smaller, quantised); "
                         "a single file's name picks its own")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_cmd_export, export_parser=s)

    s = sub.add_parser("migrate", help="convert a run folder's checkpoints written by an earlier version "
                                       "(format 1, which could hold code) to the current data-only format")
    s.add_argument("run", type=Path)
    s.add_argument("--trust", action="store_true",
                   help="you trust where this run folder came from: an old checkpoint that holds Python objects other than "
                        "tensors and plain data is read with full unpickling, which can run code")
    s.set_defaults(func=_cmd_migrate)

    s = sub.add_parser("demo", help="the headless pipeline on the built-in demo scene")
    s.add_argument("--scene", default=DEFAULT_SCENE)
    s.add_argument("--out", default="runs/demo", type=Path)
    s.add_argument("--minutes", type=float, default=3.0, help="Stage I training time")
    s.add_argument("--stage2-minutes", type=float, default=2.0, help="Stage II training time (0: Stage I only)")
    s.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    s.add_argument("--device", default=None, choices=["cpu", "cuda"], help="where to train (default: cpu)")
    s.set_defaults(func=_cmd_demo)

    from app.prepare_cmd import add_prepare_parser

    add_prepare_parser(sub)

    from app.edit_cmd import add_edit_parser

    add_edit_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        args.command = "studio"
        args.func = _cmd_studio
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, RuntimeError, ArithmeticError) as exc:
        print(f"wonderhuman-studio {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
