"""``wonderhuman-studio edit RUN``: the studio's edits, headless (docs/editing.md).

One step from the flags (``--select`` ... ``--op``), or a JSON script of steps (``--script``);
``--undo`` / ``--redo`` walk the edit history; ``--list`` prints it. The run's lock is held while
editing (a training process or studio on the run refuses the edit), and the edits are saved to
``RUN/edits`` atomically after each change.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from reconstruct.edits import selection as S
from reconstruct.edits.ops import OP_HELP, parse_op

SELECT_HELP = ("part=NAMES (head, torso, arms, *.L, ...) | rect=X0,Y0,X1,Y1@VIEW | lasso=X,Y,X,Y,X,Y,...@VIEW | "
               "brush=R:X,Y,X,Y,...@VIEW | edit=ID (an edit's mask) | all; a leading + adds, - subtracts, & intersects. "
               "VIEW: front, back, left, right, az=DEG[:EL], frame=I (that frame's training camera), eval=NAME")
STEP_KEYS = {"select", "through", "grow", "shrink", "invert", "op", "undo", "redo", "label"}


@dataclass
class Step:
    select: list[str] = field(default_factory=list)
    through: bool = False
    grow: int = 0
    shrink: int = 0
    invert: bool = False
    op: str | None = None
    undo: int = 0
    redo: int = 0
    label: str | None = None


def read_script(path: Path) -> list[Step]:
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not readable as JSON ({exc})") from exc
    steps = doc.get("steps") if isinstance(doc, dict) else doc
    if not isinstance(steps, list):
        raise ValueError(f"{path}: expected a list of steps (or {{\"steps\": [...]}})")
    out = []
    for k, d in enumerate(steps):
        if not isinstance(d, dict):
            raise ValueError(f"{path}: step {k}: expected an object, found {type(d).__name__}")
        unknown = set(d) - STEP_KEYS
        if unknown:
            raise ValueError(f"{path}: step {k}: unknown keys {sorted(unknown)} (known: {sorted(STEP_KEYS)})")
        sel = d.get("select", [])
        sel = [sel] if isinstance(sel, str) else sel
        if not isinstance(sel, list) or not all(isinstance(s, str) for s in sel):
            raise ValueError(f"{path}: step {k}: 'select' must be a string or a list of strings")
        for key, kind in (("through", bool), ("grow", int), ("shrink", int), ("invert", bool), ("undo", int),
                          ("redo", int)):
            v = d.get(key, kind())
            if not isinstance(v, kind) or (kind is int and (isinstance(v, bool) or v < 0)):
                raise ValueError(f"{path}: step {k}: '{key}' must be a{'n integer >= 0' if kind is int else ' boolean'}")
        for key in ("op", "label"):
            if d.get(key) is not None and not isinstance(d[key], str):
                raise ValueError(f"{path}: step {k}: '{key}' must be a string")
        out.append(Step(sel, d.get("through", False), d.get("grow", 0), d.get("shrink", 0), d.get("invert", False),
                        d.get("op"), d.get("undo", 0), d.get("redo", 0), d.get("label")))
    return out


def _numbers(text: str, what: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"{what}: expected comma-separated numbers, found {text!r}") from None


class ViewCameras:
    """Cameras and the snapshots they see, by VIEW name."""

    def __init__(self, avatar, frame: int, size: int) -> None:
        self.avatar, self.frame, self.size = avatar, frame, size
        self._snaps: dict[int, object] = {}

    def snapshot(self, frame: int):
        if frame not in self._snaps:
            self._snaps[frame] = self.avatar.make_snapshot("observation", frame)
        return self._snaps[frame]

    def camera(self, view: str):
        """(camera, snapshot) for VIEW."""
        from app.export import orbit_cameras
        from reconstruct.camera import Camera

        scene = self.avatar.scene
        named = {"front": 0.0, "left": 90.0, "back": 180.0, "right": 270.0}
        if view.startswith("frame="):
            i = int(view[6:])
            self.avatar.state.check_frame(i)
            return scene.frames[i].camera, self.snapshot(i)
        if view.startswith("eval="):
            name = view[5:]
            for v in scene.eval_views:
                if v.camera.name == name:
                    return v.camera, self.snapshot(v.frame_index)
            raise ValueError(f"view {view!r}: no evaluation view named {name!r} "
                             f"({', '.join(v.camera.name for v in scene.eval_views[:8])} ...)")
        if view in named or view.startswith("az="):
            az, el = (named[view], 5.0) if view in named else (_numbers(view[3:].replace(":", ","), view) + [5.0])[:2]
            snap = self.snapshot(self.frame)
            ref = orbit_cameras(snap, 1, self.size, self.size, elevation=el)[0]
            p = np.asarray(snap.means, np.float64)
            centre = 0.5 * (p.min(0) + p.max(0))
            dist = float(np.linalg.norm(ref.center - centre))
            return Camera.orbit(az, el, dist, centre, width=self.size, height=self.size, fov_y_deg=30.0, far=ref.far,
                                name=view), snap
        raise ValueError(f"view {view!r}: one of front, back, left, right, az=DEG[:EL], frame=I, eval=NAME")


def selection_of(spec: str, session, views: ViewCameras, through: bool) -> tuple[str, np.ndarray]:
    """(mode, mask) of one --select SPEC."""
    mode = {"+": "add", "-": "subtract", "&": "intersect"}.get(spec[:1], "replace")
    body = spec[1:] if mode != "replace" else spec
    kind, _, arg = body.partition("=")
    n = session.num_gaussians
    if body == "all":
        return mode, np.ones(n, bool)
    if kind == "part":
        return mode, S.part_mask(session.state.model.parts(), arg)
    if kind == "edit":
        ident = int(arg)
        for e in list(session.entries()) + session.undone:
            if e.id == ident:
                return mode, e.mask.copy()
        raise ValueError(f"--select {spec!r}: no edit #{ident}")
    if kind in ("rect", "lasso", "brush"):
        coords, at, view = arg.rpartition("@")
        if not at:
            raise ValueError(f"--select {spec!r}: needs @VIEW (front, back, left, right, az=DEG, frame=I, eval=NAME)")
        cam, snap = views.camera(view)
        if kind == "rect":
            v = _numbers(coords, spec)
            if len(v) != 4:
                raise ValueError(f"--select {spec!r}: rect needs X0,Y0,X1,Y1")
            region = S.rect_region(cam.width, cam.height, *v)
        elif kind == "lasso":
            v = _numbers(coords, spec)
            if len(v) < 6 or len(v) % 2:
                raise ValueError(f"--select {spec!r}: lasso needs at least three X,Y points")
            region = S.lasso_region(cam.width, cam.height, np.reshape(v, (-1, 2)))
        else:
            r, _, pts = coords.partition(":")
            v = _numbers(pts, spec)
            if not pts or len(v) % 2:
                raise ValueError(f"--select {spec!r}: brush needs R:X,Y[,X,Y ...]")
            region = S.brush_region(cam.width, cam.height, np.reshape(v, (-1, 2)), float(r))
        return mode, S.screen_mask(snap, cam, region, n, through=through)
    raise ValueError(f"--select {spec!r}: expected {SELECT_HELP}")


def run_steps(session, views: ViewCameras, steps: list[Step], out=print) -> None:
    for k, st in enumerate(steps):
        for _ in range(st.undo):
            e = session.undo()
            out(f"undid {e.describe()}" if e else "nothing to undo")
        for _ in range(st.redo):
            e = session.redo()
            out(f"redid {e.describe()}" if e else "nothing to redo")
        for spec in st.select:
            mode, mask = selection_of(spec, session, views, st.through)
            session.select(mask, mode, spec)
        if st.grow:
            session.grow(st.grow)
        if st.shrink:
            session.shrink(st.shrink)
        if st.invert:
            session.invert()
        if st.select or st.grow or st.shrink or st.invert:
            out(f"selected {int(session.selection.sum())} Gaussians ({session.selection_label})")
        if st.op is not None:
            e = session.apply(parse_op(st.op), label=st.label)
            out(f"applied {e.describe()}")


def edit(run_dir: Path, steps: list[Step], *, frame: int = 0, size: int = 512, list_only: bool = False) -> int:
    from reconstruct.appearance.wrap_fill import grazing_rule_for
    from reconstruct.edits.session import EditSession
    from reconstruct.run_folder import RunFolder

    run = RunFolder(run_dir)
    run.check("edit")
    with run.lock():
        trainer = run.resume()
        plan = trainer.plan if trainer.stage == 2 else None
        session = EditSession(trainer.state, run_dir=run.path, plan=plan,
                              grazing_rule=grazing_rule_for(trainer.config))
        if plan is not None:
            plan.sync_visibility(trainer.state)
        if not list_only:
            run_steps(session, ViewCameras(trainer.avatar(), frame, size), steps)
        entries = session.entries()
        print(f"{run.edits_path}: {len(entries)} edits" + (f", {len(session.undone)} undone (redo-able)"
                                                            if session.undone else ""))
        for e in entries:
            print(f"  {e.describe()}")
    return 0


def add_edit_parser(sub) -> None:
    s = sub.add_parser("edit", help="edit a trained avatar headless: select Gaussians (part, screen rectangle, lasso, "
                                    "brush) and erase, lock, recolour, paint seen/unseen or redo them; undo/redo "
                                    "(docs/editing.md)")
    s.add_argument("run", type=Path)
    s.add_argument("--select", action="append", default=[], metavar="SPEC", help=SELECT_HELP)
    s.add_argument("--through", action="store_true", help="screen selections go through the body (not only the "
                                                          "visible surface)")
    s.add_argument("--grow", type=int, default=0, metavar="TEXELS", help="grow the selection over the UV grid")
    s.add_argument("--shrink", type=int, default=0, metavar="TEXELS", help="shrink the selection over the UV grid")
    s.add_argument("--invert", action="store_true", help="invert the selection")
    s.add_argument("--op", default=None, help=OP_HELP)
    s.add_argument("--label", default=None, help="the edit's label in the list (default: the selection)")
    s.add_argument("--undo", type=int, nargs="?", const=1, default=0, metavar="N", help="undo the last N edits (1)")
    s.add_argument("--redo", type=int, nargs="?", const=1, default=0, metavar="N", help="redo N undone edits (1)")
    s.add_argument("--script", type=Path, default=None, help="a JSON list of steps (docs/editing.md)")
    s.add_argument("--frame", type=int, default=0, help="the pose (video frame) screen selections see (0)")
    s.add_argument("--size", type=int, default=512, help="pixel size of the front/back/left/right/az= views (512)")
    s.add_argument("--list", action="store_true", help="print the edits and change nothing")
    s.set_defaults(func=_cmd_edit, edit_parser=s)


def _cmd_edit(args) -> int:
    parser = args.edit_parser
    flags = bool(args.select or args.op or args.undo or args.redo or args.grow or args.shrink or args.invert)
    if args.script is not None and flags:
        parser.error("--script holds the steps; it cannot go with --select/--op/--undo/--redo")
    if args.list and (flags or args.script):
        parser.error("--list changes nothing; give it alone")
    if args.op is not None:
        parse_op(args.op)  # fail before loading anything
    if args.undo < 0 or args.redo < 0:
        parser.error("--undo and --redo take a count >= 0")
    steps = read_script(args.script) if args.script is not None else [
        Step(args.select, args.through, args.grow, args.shrink, args.invert, args.op, args.undo, args.redo, args.label)]
    if not args.list and not any(st.op or st.undo or st.redo for st in steps):
        parser.error("nothing to do: give --op (with --select), --undo, --redo, --script or --list")
    return edit(args.run, steps, frame=args.frame, size=args.size, list_only=args.list)
