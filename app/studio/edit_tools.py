"""The studio's selection tools as plain logic (no imgui, no GL): brush, rectangle and lasso strokes
on the viewport, and how they combine with the selection.

A ``Stroke`` is one drag of a tool. It fixes what it selects on when it starts -- the camera and
the snapshot the viewport drew (``StrokeView``) -- so training publishing new snapshots meanwhile
changes nothing: rows are mapped to Gaussians (texels) through ``Snapshot.ids``, and the selection
is a texel mask that holds at any pose. The visible-surface id image (the rasterizer's first hits,
``reconstruct.edits.selection.snapshot_first_hit``, ~70 ms) is computed once per stroke and every
brush dab reads it inside the dab's bounding box only (well under a millisecond); through the body,
the row centres are projected once per stroke instead.

Combine modes: replace, add, subtract, intersect (``combine``); Shift held at the press adds, Ctrl
subtracts (``combine_mode``). A brush stroke combines everything it touched so far with the
selection from before the stroke, after each dab, so the highlight follows the brush.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from reconstruct.edits import selection as S

TOOLS = ("orbit", "brush", "rect", "lasso")
TOOL_LABELS = {"orbit": "Orbit", "brush": "Brush", "rect": "Rectangle", "lasso": "Lasso"}
COMBINE_MODES = ("replace", "add", "subtract", "intersect")
LASSO_MIN_STEP = 3.0  # pixels between lasso points (a drag's mouse events are thinned to this)
MAX_RADIUS = 200.0


def combine_mode(base: str, shift: bool = False, ctrl: bool = False) -> str:
    """The combine mode of a stroke: Ctrl subtracts, Shift adds, else the panel's ``base``."""
    if base not in COMBINE_MODES:
        raise ValueError(f"combine mode {base!r}: one of {', '.join(COMBINE_MODES)}")
    return "subtract" if ctrl else "add" if shift else base


def combine(current: np.ndarray, mask: np.ndarray, mode: str) -> np.ndarray:
    """``mask`` combined with ``current`` (both (N,) bool): a new array."""
    current, mask = np.asarray(current, bool), np.asarray(mask, bool)
    if current.shape != mask.shape:
        raise ValueError(f"selections of different sizes: {current.shape} and {mask.shape}")
    if mode == "replace":
        return mask.copy()
    if mode == "add":
        return current | mask
    if mode == "subtract":
        return current & ~mask
    if mode == "intersect":
        return current & mask
    raise ValueError(f"combine mode {mode!r}: one of {', '.join(COMBINE_MODES)}")


@dataclass
class ToolSettings:
    """What the Edit panel's tool controls hold."""

    tool: str = "orbit"
    radius: float = 14.0  # brush radius, screen pixels
    through: bool = False  # select through the body (every Gaussian whose centre projects inside)
    mode: str = "replace"  # combine mode when no modifier is held

    def set_tool(self, tool: str) -> None:
        if tool not in TOOLS:
            raise ValueError(f"tool {tool!r}: one of {', '.join(TOOLS)}")
        self.tool = tool

    @property
    def selecting(self) -> bool:
        """Left drags in the viewport select (instead of orbiting)."""
        return self.tool != "orbit"


# ----- screen regions inside a bounding box ------------------------------------------------------
@dataclass(frozen=True)
class BoxRegion:
    """Pixels of a screen region, as a bool mask over the box whose top-left pixel is (x0, y0)."""

    x0: int
    y0: int
    mask: np.ndarray  # (h, w) bool

    @property
    def empty(self) -> bool:
        return self.mask.size == 0 or not self.mask.any()


def _clip_box(width: int, height: int, xa: float, ya: float, xb: float, yb: float) -> tuple[int, int, int, int]:
    x0, y0 = max(0, int(math.floor(min(xa, xb)))), max(0, int(math.floor(min(ya, yb))))
    x1, y1 = min(width, int(math.ceil(max(xa, xb))) + 1), min(height, int(math.ceil(max(ya, yb))) + 1)
    return x0, y0, max(x0, x1), max(y0, y1)


def brush_box(width: int, height: int, a, b, radius: float) -> BoxRegion:
    """Pixels (centres) within ``radius`` of the segment a-b (a dab: b = a)."""
    pts = np.asarray([a, b], np.float64)
    x0, y0, x1, y1 = _clip_box(width, height, pts[:, 0].min() - radius, pts[:, 1].min() - radius,
                               pts[:, 0].max() + radius, pts[:, 1].max() + radius)
    if x1 <= x0 or y1 <= y0:
        return BoxRegion(x0, y0, np.zeros((0, 0), bool))
    return BoxRegion(x0, y0, S.brush_region(x1 - x0, y1 - y0, pts - [x0, y0], radius))


def rect_box(width: int, height: int, a, b) -> BoxRegion:
    """Pixels whose centres lie in the rectangle between corners a and b."""
    x0, y0, x1, y1 = _clip_box(width, height, a[0], a[1], b[0], b[1])
    if x1 <= x0 or y1 <= y0:
        return BoxRegion(x0, y0, np.zeros((0, 0), bool))
    return BoxRegion(x0, y0, S.rect_region(x1 - x0, y1 - y0, a[0] - x0, a[1] - y0, b[0] - x0, b[1] - y0))


def lasso_box(width: int, height: int, polygon) -> BoxRegion:
    """Pixels (centres) inside the closed ``polygon`` ((K,2), K >= 3; even-odd rule)."""
    poly = np.asarray(polygon, np.float64).reshape(-1, 2)
    if len(poly) < 3:
        raise ValueError(f"a lasso needs at least 3 points, found {len(poly)}")
    x0, y0, x1, y1 = _clip_box(width, height, *poly.min(0), *poly.max(0))
    if x1 <= x0 or y1 <= y0:
        return BoxRegion(x0, y0, np.zeros((0, 0), bool))
    yy, xx = np.mgrid[y0:y1, x0:x1] + 0.5
    return BoxRegion(x0, y0, S.points_in_polygon(xx, yy, poly))


# ----- what a stroke selects on ------------------------------------------------------------------
@dataclass
class StrokeView:
    """The camera and snapshot a stroke selects on, with its per-stroke lookup: the first-hit row
    image (visible surface) or each row's pixel (through the body)."""

    camera: object  # reconstruct.camera.Camera of the viewport
    snapshot: object  # reconstruct.snapshot.Snapshot drawn
    through: bool
    num_gaussians: int
    first_hit: np.ndarray | None = None  # (H, W) row index, -1: nothing
    pixels: np.ndarray | None = None  # (rows, 2) int pixel of each row's centre; -1 off screen
    first_hit_ms: float = 0.0

    @staticmethod
    def make(camera, snapshot, num_gaussians: int, through: bool = False, first_hit=None) -> "StrokeView":
        """The lookup for ``camera`` and ``snapshot``: one first-hit render (``first_hit`` given:
        reused) or one projection of the row centres."""
        import time

        t0 = time.perf_counter()
        view = StrokeView(camera, snapshot, through, num_gaussians)
        if through:
            view.pixels = _row_pixels(camera, snapshot)
        else:
            view.first_hit = S.snapshot_first_hit(snapshot, camera) if first_hit is None else first_hit
        view.first_hit_ms = (time.perf_counter() - t0) * 1e3
        return view

    def rows(self, region: BoxRegion) -> np.ndarray:
        """Snapshot rows inside ``region`` (sorted, unique)."""
        if region.empty:
            return np.zeros(0, np.int64)
        h, w = region.mask.shape
        if not self.through:
            hits = self.first_hit[region.y0:region.y0 + h, region.x0:region.x0 + w][region.mask]
            return np.unique(hits[hits >= 0])
        px, py = self.pixels[:, 0] - region.x0, self.pixels[:, 1] - region.y0
        ok = (self.pixels[:, 0] >= 0) & (px >= 0) & (px < w) & (py >= 0) & (py < h)
        rows = np.flatnonzero(ok)
        return rows[region.mask[py[rows], px[rows]]]

    def gaussians(self, region: BoxRegion) -> np.ndarray:
        """(N,) bool mask of the Gaussians behind the rows inside ``region``."""
        return S.rows_to_gaussians(self.snapshot, self.rows(region), self.num_gaussians)


def _row_pixels(camera, snapshot) -> np.ndarray:
    """Each row's centre pixel under ``camera`` ((rows, 2) int; -1 behind the camera, off screen or
    transparent), as ``selection.screen_mask(through=True)`` counts them."""
    n = len(snapshot)
    out = np.full((n, 2), -1, np.int64)
    if n == 0:
        return out
    uv, z = camera.project(np.asarray(snapshot.means, np.float64))
    ok = (z > camera.near) & np.isfinite(uv).all(1) & (np.asarray(snapshot.opacities) > 0)
    px = np.floor(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    py = np.floor(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (px >= 0) & (px < camera.width) & (py >= 0) & (py < camera.height)
    out[ok, 0], out[ok, 1] = px[ok], py[ok]
    return out


# ----- a stroke ----------------------------------------------------------------------------------
@dataclass
class Stroke:
    """One drag of a selection tool: pressed at ``points[0]``, moved through the rest.

    ``before``: the selection when it began. A brush adds every dab's Gaussians to ``touched``;
    ``selection()`` is ``combine(before, touched, mode)``. A rectangle or lasso selects at
    ``finish`` (``region()``)."""

    tool: str
    mode: str
    radius: float
    before: np.ndarray
    view: StrokeView | None = None  # brush: made at the press; rectangle / lasso: at finish
    points: list[tuple[float, float]] = field(default_factory=list)
    touched: np.ndarray | None = None
    dabs: int = 0
    dab_ms: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.tool not in TOOLS or self.tool == "orbit":
            raise ValueError(f"a stroke needs a selection tool (brush, rect, lasso), found {self.tool!r}")
        if self.mode not in COMBINE_MODES:
            raise ValueError(f"combine mode {self.mode!r}: one of {', '.join(COMBINE_MODES)}")
        self.before = np.asarray(self.before, bool).copy()
        self.touched = np.zeros_like(self.before)

    @property
    def label(self) -> str:
        cam = self.view.camera.name if self.view is not None and self.view.camera.name else "view"
        through = " through" if self.view is not None and self.view.through else ""
        if self.tool == "brush":
            return f"brush r={self.radius:g} {self.dabs} dabs@{cam}{through}"
        if self.tool == "rect" and len(self.points) >= 2:
            (xa, ya), (xb, yb) = self.points[0], self.points[-1]
            return f"rect={min(xa, xb):.0f},{min(ya, yb):.0f},{max(xa, xb):.0f},{max(ya, yb):.0f}@{cam}{through}"
        return f"lasso {len(self.points)} points@{cam}{through}"

    def move(self, x: float, y: float) -> bool:
        """The mouse at (x, y). Brush: one dab along the segment from the last point (True when the
        selection changed). Rectangle: the moving corner. Lasso: a new point when far enough."""
        p = (float(x), float(y))
        if self.tool == "rect":
            self.points[1:] = [p]
            return False
        if self.tool == "lasso":
            if not self.points or math.dist(self.points[-1], p) >= LASSO_MIN_STEP:
                self.points.append(p)
            return False
        last = self.points[-1] if self.points else p
        self.points.append(p)
        return self.dab(last, p)

    def dab(self, a, b) -> bool:
        import time

        t0 = time.perf_counter()
        cam = self.view.camera
        mask = self.view.gaussians(brush_box(cam.width, cam.height, a, b, self.radius))
        grew = bool((mask & ~self.touched).any())
        self.touched |= mask
        self.dabs += 1
        self.dab_ms.append((time.perf_counter() - t0) * 1e3)
        return grew

    def selection(self) -> np.ndarray:
        """The selection with what the stroke touched so far combined in."""
        return combine(self.before, self.touched, self.mode)

    def region(self) -> BoxRegion | None:
        """A rectangle's or lasso's pixels (None when the drag is too small to be one)."""
        cam = self.view.camera
        if self.tool == "rect":
            if len(self.points) < 2:
                return None
            return rect_box(cam.width, cam.height, self.points[0], self.points[-1])
        if self.tool == "lasso":
            return lasso_box(cam.width, cam.height, self.points) if len(self.points) >= 3 else None
        return None
