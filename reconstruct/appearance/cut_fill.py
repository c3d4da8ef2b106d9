"""Colours past the frame's edge: the body a photo or a video cuts off (a portrait cut at the waist,
a photo cut at the knees) is in no training image at all, so nothing says what it wears. The wrap
fill's part rules guess from the part's own seen edge, and a part with no seen Gaussian at all takes
the nearest filled colour of any part: on a long-skirt photo cut at the hips the right thigh's back
took the dark edge of the skirt's silhouette and its shin and foot followed it (near black), while
the left leg came out navy.

Here every limb (both legs, both arms: ``CHAINS``) and the trunk past the edge take one colour: what
the images show where the limb crosses the edge -- the person's pixels (mask > 0.5) within
``edge_px`` of the edge under the limb's Gaussians that project there, whatever covers the limb (a
skirt over the thighs). The clothes at the edge go on past it. A pair of limbs pools both sides, so
that two legs past the same edge wear the same; a limb whose own crossing shows too little (a
portrait cut above the hips: no thigh in view) takes the person's pixels along every edge the body
crosses."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..body.parts import PART_INDEX, PART_NAMES

EDGES = ("left", "right", "top", "bottom")
# the body's chains of parts: a group of one chain per side (limbs) or one chain (the trunk)
CHAINS: tuple[tuple[tuple[str, ...], ...], ...] = (
    (("thigh.L", "shin.L", "foot.L"), ("thigh.R", "shin.R", "foot.R")),
    (("upperarm.L", "lowerarm.L", "hand.L"), ("upperarm.R", "lowerarm.R", "hand.R")),
    (("torso", "neck", "head"),),
)


def _near_edges(x: np.ndarray, y: np.ndarray, w: int, h: int, edges, edge_px: float) -> np.ndarray:
    """Where (x, y) (pixel coordinates; any shapes that broadcast) lie within ``edge_px`` of one of
    the ``edges`` of a ``w`` x ``h`` image (or past it)."""
    near = np.zeros(np.broadcast(x, y).shape, bool)
    for e in edges:
        near |= {"left": x < edge_px, "right": x >= w - edge_px, "top": y < edge_px, "bottom": y >= h - edge_px}[e]
    return near


@dataclass
class FrameView:
    """One training frame as the cut sees it: each Gaussian's projection ``uv`` (N,2) in the frame's
    whole image (pixels, x right, y down), ``in_front`` (N,) of its camera, the ``image`` (H,W,3) in
    [0,1] and the person ``mask`` (H,W)."""

    uv: np.ndarray
    in_front: np.ndarray
    image: np.ndarray
    mask: np.ndarray

    def inside(self) -> np.ndarray:
        h, w = self.mask.shape
        u, v = self.uv[:, 0], self.uv[:, 1]
        return self.in_front & (u >= 0) & (u < w) & (v >= 0) & (v < h)

    def beyond_edges(self, which: np.ndarray) -> list[str]:
        """The image's edges (``top``, ``bottom``, ``left``, ``right``) past which some of ``which``
        (bool) project."""
        h, w = self.mask.shape
        u, v, f = self.uv[:, 0], self.uv[:, 1], self.in_front & which
        return [e for e in EDGES if bool((_near_edges(u, v, w, h, (e,), 0.0) & f).any())]

    def edge_samples(self, which: np.ndarray, edges: list[str], edge_px: float) -> np.ndarray:
        """(S,3): the image's colours under those of ``which`` that project into it within
        ``edge_px`` of one of ``edges``, where the mask shows the person."""
        h, w = self.mask.shape
        u, v = self.uv[:, 0], self.uv[:, 1]
        k = which & self.inside() & _near_edges(u, v, w, h, edges, edge_px)
        x, y = np.floor(u[k]).astype(np.int64), np.floor(v[k]).astype(np.int64)
        on = self.mask[y, x] > 0.5
        return np.asarray(self.image, np.float64)[y[on], x[on]]

    def person_along(self, edges: list[str], edge_px: float) -> np.ndarray:
        """(S,3): the colours of the person's pixels within ``edge_px`` of ``edges``."""
        h, w = self.mask.shape
        near = _near_edges(np.arange(w)[None, :], np.arange(h)[:, None], w, h, edges, edge_px)
        return np.asarray(self.image, np.float64)[near & (self.mask > 0.5)]


def cut_colors(parts: np.ndarray, out_of_view: np.ndarray, frames: Iterable[FrameView], *, edge_px: float,
               k: int = 8) -> np.ndarray:
    """(N,3) float32: for each body Gaussian ``out_of_view`` (in no frame's image), the per-channel
    median colour the frames show where its group of ``CHAINS`` crosses the image's edge (module
    docstring), NaN elsewhere (and for a group whose crossing, and the person's pixels along every
    edge the body crosses, show fewer than ``k`` pixels). ``parts`` (N,): part indices (a garment
    layer's past the body's, never set). ``frames`` is read once (a generator may pose them one by
    one)."""
    parts = np.asarray(parts)
    beyond = np.asarray(out_of_view, bool)
    if beyond.shape != parts.shape:
        raise ValueError(f"cut_colors: out_of_view has shape {beyond.shape}, the parts {parts.shape}")
    out = np.full((len(parts), 3), np.nan, np.float32)
    body = parts < len(PART_NAMES)
    groups = [[np.isin(parts, [PART_INDEX[p] for p in side]) for side in group] for group in CHAINS]
    groups = [g for g in groups if (np.logical_or.reduce(g) & beyond).any()]
    if not groups:
        return out
    samples: list[list[np.ndarray]] = [[] for _ in groups]
    whole: list[np.ndarray] = []
    for f in frames:
        for g, sides in enumerate(groups):
            for member in sides:
                edges = f.beyond_edges(member)
                if edges:
                    samples[g].append(f.edge_samples(member, edges, edge_px))
        whole.append(f.person_along(f.beyond_edges(body), edge_px))
    every = np.concatenate(whole + [np.zeros((0, 3))])
    for g, sides in enumerate(groups):
        got = np.concatenate(samples[g] + [np.zeros((0, 3))])
        if len(got) < k:
            got = every
        if len(got) >= k:
            out[np.logical_or.reduce(sides) & beyond] = np.median(got, axis=0)
    return out


def apply_cut_colors(colors: np.ndarray, parts: np.ndarray, seen: np.ndarray, cut: np.ndarray,
                     under_layer: np.ndarray | None = None) -> np.ndarray:
    """``colors`` (N,3) with the body's Gaussians that are not ``seen`` and have a cut colour
    (``cut``: (N,3), NaN where none) set to it; not those a garment layer hides (``under_layer`` >=
    0, as in ``wrap_fill_colors``: they show the layer's colour)."""
    out = np.array(colors, np.float64, copy=True)
    cut = np.asarray(cut, np.float64)
    if cut.shape != out.shape:
        raise ValueError(f"apply_cut_colors: the cut colours have shape {cut.shape}, the colours {out.shape}")
    todo = np.isfinite(cut).all(1) & ~np.asarray(seen, bool) & (np.asarray(parts) < len(PART_NAMES))
    if under_layer is not None:
        todo &= np.asarray(under_layer) < 0
    out[todo] = cut[todo]
    return out
