"""The editor of one studio window (GL thread): the selection tools on the viewport, the highlight of
the selection, and the edit actions, which go to the trainer thread's queue.

Who does what:
* the selection is the trainer thread's ``EditSession.selection`` (a texel mask); only the GL
  thread changes it (strokes, parts, grow / shrink / invert / clear) and only the GL thread reads
  it -- apply hands the trainer thread a copy;
* apply / undo / redo / guidance steps: ``TrainerThread.edit`` / ``guidance_steps`` -> a Future;
  the Edit panel shows "applying..." until it is done, and the trainer publishes a new snapshot
  after it, which the next frame draws. One request at a time.
* strokes: ``edit_tools.Stroke`` on the camera and avatar snapshot the viewport drew last
  (``StudioApp.drawn_view``); the brush updates the selection (and so the highlight) at every dab.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np

from .edit_tools import Stroke, StrokeView, ToolSettings, combine_mode


@dataclass
class StrokeTiming:
    """One stroke's costs (ms): the first-hit render, its dabs (a rectangle's or lasso's selection),
    the highlight gathers, and from each input that changed the selection (the press: with the
    first-hit render) to the end of the frame that showed it (``glfw.swap_buffers`` returned)."""

    tool: str
    first_hit_ms: float = 0.0
    dab_ms: list[float] = field(default_factory=list)
    highlight_ms: list[float] = field(default_factory=list)
    to_frame_ms: list[float] = field(default_factory=list)  # [0]: from the press (brush)


@dataclass
class EditPanelState:
    """What the Edit panel shows and edits (besides the tool settings)."""

    part: str = "head"
    hue: float = 30.0
    saturation: float = 1.0
    value: float = 1.0
    guidance_steps: int = 20
    pending: Future | None = None
    pending_what: str = ""
    message: str | None = None  # the last error
    result: str | None = None  # what the last request did


class EditController:
    def __init__(self, app) -> None:
        self.app = app
        self.tools = ToolSettings()
        self.panel = EditPanelState()
        self.stroke: Stroke | None = None
        self.stroke_by_mouse = False  # the stroke follows the left button (edit_input.handle_mouse)
        self.timings: list[StrokeTiming] = []
        self._hl_key: tuple | None = None
        self._hl_snap = None
        self._changed_at: float | None = None  # when the selection last changed (latency)
        self._changed_sel = None
        self._pending_view = None  # (camera, snapshot) a rectangle or lasso selects on at its release

    # ----- state ------------------------------------------------------------------------------
    @property
    def session(self):
        return self.app.trainer.edit_session

    @property
    def error(self) -> str | None:
        return self.app.trainer.edit_error

    @property
    def busy(self) -> bool:
        return self.panel.pending is not None

    @property
    def selected_count(self) -> int:
        s = self.session
        return 0 if s is None else int(np.count_nonzero(s.selection))

    def change_key(self) -> tuple:
        s, p = self.session, self.panel
        if s is None:
            return (self.error,)
        return (id(s.selection), len(s.state.edits), len(s.undone), p.pending is not None, p.message, p.result,
                self.tools.tool)

    def entries(self) -> list[tuple[object, bool]]:
        """The edits made, oldest first: (EditEntry, applied); undone ones after the applied."""
        s = self.session
        if s is None:
            return []
        return [(e, True) for e in s.entries()] + [(e, False) for e in reversed(list(s.undone))]

    # ----- the selection (GL thread) -------------------------------------------------------------
    def _selection_changed(self, since: float | None = None) -> None:
        """The selection changed (because of input handled since ``since``): latency is counted from then."""
        self._changed_at = time.perf_counter() if since is None else since
        self._changed_sel = self.session.selection

    def select_part(self, name: str | None = None, mode: str | None = None) -> None:
        s = self.session
        if s is None:
            return
        try:
            s.select_part(name or self.panel.part, mode or self.tools.mode)
        except ValueError as exc:
            self.panel.message = str(exc)
            return
        self._selection_changed()

    def grow(self, texels: int = 1) -> None:
        if self.session is not None:
            self.session.grow(texels)
            self._selection_changed()

    def shrink(self, texels: int = 1) -> None:
        if self.session is not None:
            self.session.shrink(texels)
            self._selection_changed()

    def invert(self) -> None:
        if self.session is not None:
            self.session.invert()
            self._selection_changed()

    def clear(self) -> None:
        if self.session is not None:
            self.session.clear()
            self._selection_changed()

    def set_tool(self, tool: str) -> None:
        self.cancel_stroke()
        self.tools.set_tool(tool)
        if self.tools.selecting:
            self.app.view.edit_panel = True

    # ----- strokes (GL thread) ---------------------------------------------------------------------
    def begin_stroke(self, x: float, y: float, shift: bool = False, ctrl: bool = False) -> bool:
        """Press at viewport pixel (x, y) with the current tool; False when nothing was drawn yet."""
        s, drawn = self.session, self.app.drawn_view
        if s is None or drawn is None or not self.tools.selecting:
            return False
        t0 = time.perf_counter()
        camera, snapshot = drawn
        t = self.tools
        self.stroke_by_mouse = False
        self.stroke = Stroke(t.tool, combine_mode(t.mode, shift, ctrl), float(t.radius), s.selection)
        self.timings.append(StrokeTiming(t.tool))
        if t.tool == "brush":
            self.stroke.view = StrokeView.make(camera, snapshot, s.num_gaussians, t.through)
            self.timings[-1].first_hit_ms = self.stroke.view.first_hit_ms
            self.stroke.move(x, y)
            self.timings[-1].dab_ms.append(self.stroke.dab_ms[-1])
            self._show_stroke(t0)
        else:
            self.stroke.points = [(float(x), float(y))] * (2 if t.tool == "rect" else 1)
            self._pending_view = (camera, snapshot)
        return True

    def move_stroke(self, x: float, y: float) -> None:
        st = self.stroke
        if st is None:
            return
        t0 = time.perf_counter()
        n = len(st.dab_ms)
        if st.move(x, y):
            self._show_stroke(t0)
        if st.tool == "brush" and len(st.dab_ms) > n:
            self.timings[-1].dab_ms.append(st.dab_ms[-1])

    def _show_stroke(self, since: float | None = None) -> None:
        self.session.selection = self.stroke.selection()
        self._selection_changed(since)

    def finish_stroke(self, x: float | None = None, y: float | None = None) -> None:
        """Release: a brush keeps what it painted (labelled); a rectangle or lasso selects now (one
        first-hit render)."""
        st, s = self.stroke, self.session
        self.stroke = None
        if st is None or s is None:
            return
        if x is not None and st.tool != "brush":
            st.move(x, y)
        if st.tool == "brush":
            s.selection = st.before
            s.select(st.touched, st.mode, st.label)
            self._selection_changed()
            return
        camera, snapshot = self._pending_view
        t0 = time.perf_counter()
        st.view = StrokeView.make(camera, snapshot, s.num_gaussians, self.tools.through)
        self.timings[-1].first_hit_ms = st.view.first_hit_ms
        region = st.region()
        if region is None:
            return
        s.select(st.view.gaussians(region), st.mode, st.label)
        self.timings[-1].dab_ms.append((time.perf_counter() - t0) * 1e3 - st.view.first_hit_ms)
        self._selection_changed(t0)

    def cancel_stroke(self) -> None:
        st, self.stroke = self.stroke, None
        if st is not None and self.session is not None and st.tool == "brush":
            self.session.selection = st.before
            self._selection_changed()

    # ----- the highlight (GL thread, per frame) -----------------------------------------------------
    def highlighted(self, drawn, avatar):
        """``drawn`` (the avatar snapshot, or it with a .ply beside it) with ``highlight`` set on the
        avatar's selected rows (cached: the same object until the snapshot or the selection
        changes, so the renderer uploads the highlight attribute only then)."""
        s = self.session
        if s is None or not s.selection.any():
            return drawn
        key = (drawn, drawn.version, avatar, s.selection)
        if self._hl_key is not None and all(a is b for a, b in zip(key, self._hl_key)):
            return self._hl_snap
        t0 = time.perf_counter()
        h = s.highlight(avatar)
        if len(drawn) != len(h):  # rows of a .ply beside the avatar: never highlighted
            h = np.concatenate([h, np.zeros(len(drawn) - len(h), np.uint8)])[:len(drawn)]
        self._hl_key, self._hl_snap = key, dataclasses.replace(drawn, highlight=h)
        if self.timings and self._changed_at is not None:
            self.timings[-1].highlight_ms.append((time.perf_counter() - t0) * 1e3)
        return self._hl_snap

    def frame_shown(self) -> None:
        """After the frame was swapped: the latency of a selection change it showed."""
        s = self.session
        if self._changed_at is None or s is None or self._changed_sel is not s.selection:
            return
        if self._hl_key is not None and self._hl_key[3] is s.selection and self.timings:
            self.timings[-1].to_frame_ms.append((time.perf_counter() - self._changed_at) * 1e3)
            self._changed_at = None

    # ----- edits (trainer thread, through its queue) ---------------------------------------------------
    def _request(self, what: str, future: Future) -> None:
        p = self.panel
        p.pending, p.pending_what, p.message = future, what, None

    def apply(self, op) -> bool:
        """Apply ``op`` (a ``reconstruct.edits`` Op) to the selection, between training steps."""
        s, p = self.session, self.panel
        if s is None or self.busy:
            p.message = self.error if s is None else f"wait: {p.pending_what}"
            return False
        mask, label = s.selection.copy(), s.selection_label
        if not mask.any():
            p.message = f"{op.describe()}: nothing is selected"
            return False
        self._request(f"{op.describe()} on {int(mask.sum())} Gaussians",
                      self.app.trainer.edit(lambda session: session.apply(op, mask=mask, label=label)))
        return True

    def undo(self) -> bool:
        s = self.session
        if s is None or self.busy or not s.can_undo:
            return False
        self._request("undo", self.app.trainer.edit(lambda session: session.undo()))
        return True

    def redo(self) -> bool:
        s = self.session
        if s is None or self.busy or not s.can_redo:
            return False
        self._request("redo", self.app.trainer.edit(lambda session: session.redo()))
        return True

    def run_guidance(self, steps: int | None = None) -> bool:
        if self.busy:
            return False
        n = int(self.panel.guidance_steps if steps is None else steps)
        self._request(f"{n} guidance steps", self.app.trainer.guidance_steps(n))
        return True

    def poll(self) -> None:
        """GL thread, once a frame: take a finished request (never waits)."""
        p = self.panel
        fut = p.pending
        if fut is None or not fut.done():
            return
        p.pending = None
        exc = fut.exception()
        if exc is not None:
            p.message, p.result = f"{p.pending_what}: {exc}", None
            print(f"wonderhuman-studio: {p.message}", file=sys.stderr)
            return
        out = fut.result()
        if p.pending_what in ("undo", "redo"):
            p.result = f"{p.pending_what}: {out.describe()}" if out is not None else f"nothing to {p.pending_what}"
        elif isinstance(out, int):
            p.result = f"ran {out} guidance steps"
        else:
            p.result = f"applied {out.describe()}"
