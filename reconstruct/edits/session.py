"""EditSession: what the studio's tools and the headless ``edit`` command work with.

    session = EditSession(trainer.state, run_dir=run.path, plan=trainer.plan)   # loads RUN/edits
    session.select_part("head")                                  # or select_rect / select_brush / select_lasso
    session.select_rect(camera, snapshot, (x0, y0, x1, y1))      # visible surface; through=True: the whole body
    session.grow(2); session.invert(); session.clear()
    entry = session.apply(Erase())                               # Lock(), Recolour(30, 1, 0.8), PaintUnseen(), Redo()
    session.undo(); session.redo(); session.entries()            # saved to RUN/edits after each change
    snap = session.highlighted(snapshot)                         # Snapshot.highlight: 1 on selected rows

Each change of the edit list replaces ``state.edits`` (an immutable ``EditList``): undo brings the
avatar back bit-exactly. Changes of the painted visibility during Stage II redo the plan's view
selection and propagated appearance (``plan.refresh_visibility``). The studio applies edits between
training steps (the trainer thread's queue), as it does other changes of the state.
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch

from . import selection as S
from .edit_list import EditEntry, EditList, model_parameters
from .ops import Lock, Op, PaintSeen, PaintUnseen, Redo
from .store import load_edits, save_edits

if TYPE_CHECKING:
    from ..avatar.state import AvatarState

MODES = ("replace", "add", "subtract", "intersect")
VISIBILITY_OPS = (PaintSeen, PaintUnseen, Redo)


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


class EditSession:
    def __init__(self, state: AvatarState, *, run_dir=None, plan=None, load: bool = True,
                 autosave: bool = True, seen_erosion: int = 2, grazing_rule: bool = True) -> None:
        """Edits of ``state``; with ``run_dir`` they are loaded from (``load``) and saved to
        ``RUN/edits`` (``autosave``: after every change). ``plan``: the running Stage II plan, whose
        views and propagated colours follow the painted visibility. ``seen_erosion``: texels the
        Stage I flags are shrunk by for redo's propagated colours before Stage II has its own.
        ``grazing_rule``: the wrap fill's rule for grazing seen colours (``grazing_rule_for`` the
        run's Stage I settings)."""
        self.state = state
        self.run_dir = run_dir
        self.plan = plan
        self.autosave = autosave
        self.seen_erosion = seen_erosion
        self.grazing_rule = grazing_rule
        self.undone: list[EditEntry] = []
        self.next_id = max((e.id for e in state.edits), default=0) + 1
        if run_dir is not None and load:
            stored = load_edits(run_dir, state.num_gaussians, state.model)
            state.edits = stored.applied
            self.undone, self.next_id = list(stored.undone), stored.next_id
        self.selection = np.zeros(state.num_gaussians, bool)
        self.selection_label = ""
        self._neighbours: np.ndarray | None = None
        self.listeners: list[Callable[[EditSession], None]] = []  # called after every change of the edit list

    # ----- the selection --------------------------------------------------------------------
    @property
    def num_gaussians(self) -> int:
        return self.state.num_gaussians

    @property
    def neighbours(self) -> np.ndarray:
        if self._neighbours is None or len(self._neighbours) != self.num_gaussians:
            self._neighbours = self.state.model.neighbours()  # a garment layer's Gaussians over its own grid
        return self._neighbours

    def select(self, mask: np.ndarray, mode: str = "replace", label: str = "") -> np.ndarray:
        """Combine ``mask`` with the selection (replace, add, subtract, intersect)."""
        mask = np.asarray(mask, bool)
        if mask.shape != (self.num_gaussians,):
            raise ValueError(f"a selection is one bool per Gaussian ({self.num_gaussians}), found shape {mask.shape}")
        if mode not in MODES:
            raise ValueError(f"selection mode {mode!r}: one of {', '.join(MODES)}")
        cur = self.selection
        self.selection = {"replace": mask, "add": cur | mask, "subtract": cur & ~mask, "intersect": cur & mask}[mode]
        if label:
            self.selection_label = label if mode == "replace" or not self.selection_label else \
                f"{self.selection_label} {mode} {label}"
        return self.selection

    def select_part(self, names, mode: str = "replace") -> np.ndarray:
        return self.select(S.part_mask(self.state.model.parts(), names), mode, f"part={names}")

    def select_region(self, camera, snapshot, region: np.ndarray, *, through: bool = False, mode: str = "replace",
                      label: str = "", first_hit: np.ndarray | None = None) -> np.ndarray:
        return self.select(S.screen_mask(snapshot, camera, region, self.num_gaussians, through=through,
                                         first_hit=first_hit), mode, label)

    def select_rect(self, camera, snapshot, rect, *, through: bool = False, mode: str = "replace",
                    first_hit: np.ndarray | None = None) -> np.ndarray:
        x0, y0, x1, y1 = rect
        region = S.rect_region(camera.width, camera.height, x0, y0, x1, y1)
        return self.select_region(camera, snapshot, region, through=through, mode=mode, first_hit=first_hit,
                                  label=f"rect={x0:g},{y0:g},{x1:g},{y1:g}@{camera.name or 'camera'}"
                                        + (" through" if through else ""))

    def select_brush(self, camera, snapshot, points, radius: float, *, through: bool = False, mode: str = "add",
                     first_hit: np.ndarray | None = None) -> np.ndarray:
        region = S.brush_region(camera.width, camera.height, points, radius)
        return self.select_region(camera, snapshot, region, through=through, mode=mode, first_hit=first_hit,
                                  label=f"brush r={radius:g}@{camera.name or 'camera'}")

    def select_lasso(self, camera, snapshot, polygon, *, through: bool = False, mode: str = "replace",
                     first_hit: np.ndarray | None = None) -> np.ndarray:
        region = S.lasso_region(camera.width, camera.height, polygon)
        return self.select_region(camera, snapshot, region, through=through, mode=mode, first_hit=first_hit,
                                  label=f"lasso {len(polygon)} points@{camera.name or 'camera'}")

    def grow(self, texels: int = 1) -> np.ndarray:
        self.selection = S.grow(self.selection, self.neighbours, texels)
        return self.selection

    def shrink(self, texels: int = 1) -> np.ndarray:
        self.selection = S.shrink(self.selection, self.neighbours, texels)
        return self.selection

    def invert(self) -> np.ndarray:
        self.selection = ~self.selection
        self.selection_label = f"not ({self.selection_label})" if self.selection_label else ""
        return self.selection

    def clear(self) -> np.ndarray:
        self.selection = np.zeros(self.num_gaussians, bool)
        self.selection_label = ""
        return self.selection

    def highlight(self, snapshot) -> np.ndarray:
        """(rows,) uint8 for ``snapshot``: 1 where the row's Gaussian is selected (a per-Gaussian
        flag the renderer can show; cheap: one gather)."""
        ids = getattr(snapshot, "ids", None)
        sel = self.selection if ids is None else self.selection[np.asarray(ids)]
        return sel.astype(np.uint8)

    def highlighted(self, snapshot):
        return dataclasses.replace(snapshot, highlight=self.highlight(snapshot))

    # ----- the edit list --------------------------------------------------------------------
    def entries(self) -> list[EditEntry]:
        return list(self.state.edits)

    @property
    def can_undo(self) -> bool:
        return bool(self.state.edits)

    @property
    def can_redo(self) -> bool:
        return bool(self.undone)

    def apply(self, op: Op, mask: np.ndarray | None = None, label: str | None = None) -> EditEntry:
        """``op`` on ``mask`` (default: the selection). Clears the redo stack."""
        mask = np.array(self.selection if mask is None else mask, dtype=bool, copy=True)
        if mask.shape != (self.num_gaussians,):
            raise ValueError(f"a mask is one bool per Gaussian ({self.num_gaussians}), found shape {mask.shape}")
        if not mask.any():
            raise ValueError(f"{op.describe()}: nothing is selected")
        label = self.selection_label if label is None else label
        entry = EditEntry(self.next_id, op, mask, label, _now())
        with torch.no_grad():
            if isinstance(op, Lock):
                entry = dataclasses.replace(entry, lock_params=model_parameters(self.state.model), _runtime={})
            elif isinstance(op, Redo):
                entry = self._redo_entry(entry)
        self.next_id += 1
        self.undone = []
        self._set(self.state.edits.appended(entry), visibility=isinstance(op, VISIBILITY_OPS))
        return entry

    def _redo_entry(self, entry: EditEntry) -> EditEntry:
        """A redo: offsets that make the region's canonical colours the prior's pseudo-colours,
        propagated with the region painted unseen."""
        state = self.state
        before = state.edits
        base = state.canonical(None).colors.detach()  # with the edits before this one
        trial = dataclasses.replace(entry, color_offset=np.zeros((entry.count, 3), np.float32), _runtime={})
        state.edits = before.appended(trial)
        try:
            target = self._pseudo_colours()
        finally:
            state.edits = before
        m = torch.as_tensor(entry.mask, device=base.device)
        lg = lambda c: torch.logit(c.clamp(1e-6, 1 - 1e-6))  # noqa: E731
        off = (lg(target.to(base.device)[m]) - lg(base[m])).float().cpu().numpy()
        return dataclasses.replace(entry, color_offset=off, _runtime={})

    def _pseudo_colours(self) -> torch.Tensor:
        """The prior's appearance for the current (trial) painted flags: the Stage II plan's
        propagated colours, or the same wrap-around fill from the Stage I flags (eroded). Regions
        under a redo take its low-frequency fill only, never a mirrored colour."""
        state = self.state
        if self.plan is not None and hasattr(self.plan, "refresh_visibility"):
            self.plan.refresh_visibility(state)
            return self.plan.pseudo_colors
        from ..appearance.propagation import erode_by_part
        from ..appearance.pseudo_appearance import pseudo_appearance

        trusted = state.trusted_seen
        if trusted is None:
            trusted = state.edits.paint(torch.as_tensor(
                erode_by_part(state.seen.numpy(), self.neighbours, state.model.parts(), self.seen_erosion)))
        return pseudo_appearance(state, trusted, state.canonical(None).colors, self.neighbours, self.seen_erosion,
                                 grazing_rule=self.grazing_rule)

    def undo(self) -> EditEntry | None:
        """Removes the last edit (kept for ``redo``); None when there is none."""
        if not self.state.edits:
            return None
        entry = self.state.edits.entries[-1]
        self.undone.append(entry)
        self._set(self.state.edits.without_last(), visibility=isinstance(entry.op, VISIBILITY_OPS))
        return entry

    def redo(self) -> EditEntry | None:
        """Applies the last undone edit again; None when there is none."""
        if not self.undone:
            return None
        entry = self.undone.pop()
        self._set(self.state.edits.appended(entry), visibility=isinstance(entry.op, VISIBILITY_OPS))
        return entry

    def _set(self, edits: EditList, *, visibility: bool) -> None:
        self.state.edits = edits
        if visibility and self.plan is not None and hasattr(self.plan, "sync_visibility"):
            self.plan.sync_visibility(self.state)
        if self.autosave and self.run_dir is not None:
            self.save()
        for f in self.listeners:
            f(self)

    def save(self):
        if self.run_dir is None:
            raise ValueError("this edit session has no run folder to save to")
        return save_edits(self.run_dir, self.state.edits, self.undone, self.next_id)
