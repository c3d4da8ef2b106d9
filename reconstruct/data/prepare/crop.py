"""One steady crop around the person for the whole clip, resized to the working size, and the camera
intrinsics that go with it (principal point moved by the crop's corner, focal scaled with the resize).

A crop maps a source pixel position p to (p - corner) * scale. Pixel centres sit at +0.5 in both images,
so continuous coordinates map exactly by that formula."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Crop:
    """Source box (x0, y0) + (width, height) in source pixels (may reach outside the frame: padded black),
    resized to out_width x out_height."""

    x0: float
    y0: float
    width: float
    height: float
    out_width: int
    out_height: int

    @property
    def scale(self) -> float:
        return self.out_width / self.width

    def to_crop(self, uv: np.ndarray) -> np.ndarray:
        """Source pixel positions (...,2) -> crop pixel positions."""
        return (np.asarray(uv, np.float64) - [self.x0, self.y0]) * [self.out_width / self.width,
                                                                     self.out_height / self.height]

    def intrinsics(self, K: np.ndarray) -> np.ndarray:
        """The source camera's K (3,3) -> the crop's K."""
        sx, sy = self.out_width / self.width, self.out_height / self.height
        A = np.array([[sx, 0.0, -sx * self.x0], [0.0, sy, -sy * self.y0], [0.0, 0.0, 1.0]])
        return A @ np.asarray(K, np.float64)

    def to_dict(self) -> dict:
        return {"x0": self.x0, "y0": self.y0, "width": self.width, "height": self.height,
                "out_width": self.out_width, "out_height": self.out_height}


# a person's box within this share of the frame's longer side of one of its edges reaches that edge
BOX_AT_EDGE = 0.01


def _inside_cut_edges(lo: float, size: float, extent: float, at_lo: bool, at_hi: bool) -> float:
    """The crop's start along one axis, moved so that the crop (``size`` long, no longer than the
    frame's ``extent``) does not reach past an edge the person's box reaches (``at_lo``: the frame's
    start, ``at_hi``: its end)."""
    if at_hi and lo + size > extent:
        lo = extent - size
    if at_lo and lo < 0:
        lo = 0.0
    return lo


def person_crop(box: tuple[float, float, float, float] | None, width: int, height: int, out_size: int,
                *, margin: float = 0.1, min_aspect: float = 0.75, edge_reach: float | None = None) -> Crop:
    """The crop around ``box`` (x0, y0, x1, y1): grown by ``margin`` of its height on every side, widened to
    at least ``min_aspect`` (width / height; a square-ish frame for a standing person), its longer side
    resized to ``out_size``. None or a box of the whole frame: the whole frame.

    Padding (black, past the frame) is never put beyond an edge of the frame that the box reaches
    (within ``edge_reach`` source pixels; default ``BOX_AT_EDGE`` of the frame's longer side): the
    frame cuts the person off there, and a padded band would say that nothing lies past the edge --
    the mask is empty in it -- where the person goes on unseen. (A photo cut at the knees with room
    above the head: the silhouette fit bent the legs back out of the band, and training would empty
    them.) The crop is moved inwards instead, or, where it is longer than the frame, is the frame's
    extent along that axis."""
    if box is None:
        x0, y0, x1, y1 = 0.0, 0.0, float(width), float(height)
    else:
        x0, y0, x1, y1 = box
        m = margin * max(y1 - y0, x1 - x0)
        x0, y0, x1, y1 = x0 - m, y0 - m, x1 + m, y1 + m
    w, h = x1 - x0, y1 - y0
    if w < min_aspect * h:
        cx = 0.5 * (x0 + x1)
        w = min_aspect * h
        x0 = cx - w / 2
    elif h < min_aspect * w:
        cy = 0.5 * (y0 + y1)
        h = min_aspect * w
        y0 = cy - h / 2
    # no padding where the frame itself is narrower (or lower) than the crop: take the frame's extent
    if box is not None and w > width:
        x0, w = 0.0, float(width)
    if box is not None and h > height:
        y0, h = 0.0, float(height)
    # whole pixels for the corner and size keep the resampling simple; same aspect in and out
    x0, y0 = float(np.floor(x0)), float(np.floor(y0))
    w, h = float(np.ceil(w)), float(np.ceil(h))
    if box is not None:
        reach = BOX_AT_EDGE * max(width, height) if edge_reach is None else edge_reach
        bx0, by0, bx1, by1 = box
        x0 = _inside_cut_edges(x0, w, width, bx0 <= reach, bx1 >= width - reach)
        y0 = _inside_cut_edges(y0, h, height, by0 <= reach, by1 >= height - reach)
    s = out_size / max(w, h)
    ow, oh = max(8, int(round(w * s))), max(8, int(round(h * s)))
    return Crop(x0, y0, w, h, ow, oh)


def apply_crop(images: np.ndarray, crop: Crop, *, resample: str = "lanczos") -> np.ndarray:
    """Crop (N,H,W[,C]) images (uint8 or float) to ``crop`` (black outside the source) and resize."""
    from PIL import Image

    out = []
    mode = {"lanczos": Image.Resampling.LANCZOS, "bilinear": Image.Resampling.BILINEAR,
            "nearest": Image.Resampling.NEAREST}[resample]
    for im in images:
        H, W = im.shape[:2]
        x0, y0, w, h = int(crop.x0), int(crop.y0), int(crop.width), int(crop.height)
        canvas = np.zeros((h, w) + im.shape[2:], im.dtype)
        sx0, sy0, sx1, sy1 = max(0, x0), max(0, y0), min(W, x0 + w), min(H, y0 + h)
        if sx1 > sx0 and sy1 > sy0:
            canvas[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = im[sy0:sy1, sx0:sx1]
        if canvas.dtype == np.uint8:
            out.append(np.asarray(Image.fromarray(canvas).resize((crop.out_width, crop.out_height), mode)))
        else:
            chans = canvas[..., None] if canvas.ndim == 2 else canvas
            res = [np.asarray(Image.fromarray(chans[..., c].astype(np.float32), mode="F").resize(
                (crop.out_width, crop.out_height), Image.Resampling.BILINEAR if mode == Image.Resampling.LANCZOS else mode))
                for c in range(chans.shape[-1])]
            r = np.stack(res, -1)
            out.append(r[..., 0] if canvas.ndim == 2 else r)
    return np.stack(out)


EDGES = ("top", "bottom", "left", "right")


def edge_lines(crop: Crop, source_size: tuple[int, int]) -> dict[str, tuple[float, int]]:
    """{edge: (position, inward)}: each edge of the source frame in crop pixels (a row for the top
    and the bottom, a column for the sides), and the side of it that lies inside the frame (+1:
    larger coordinates)."""
    W0, H0 = source_size
    sx, sy = crop.out_width / crop.width, crop.out_height / crop.height
    return {"top": (-crop.y0 * sy, +1), "bottom": ((H0 - crop.y0) * sy, -1),
            "left": (-crop.x0 * sx, +1), "right": ((W0 - crop.x0) * sx, -1)}


def edges_cut(mask: np.ndarray, crop: Crop, source_size: tuple[int, int], *, reach: float = 2.0,
              min_share: float = 0.02) -> list[str]:
    """The edges of the source frame that cut the person off, in one mask in crop pixels (H, W):
    those of ``EDGES`` along which the person (mask > 0.5) reaches within ``reach`` crop pixels of
    the edge over at least ``min_share`` of the crop's side (a photo cut at the knees: both legs at
    the bottom edge). An edge outside the crop (the crop lies inside the frame there) or in its
    padding cuts nothing. ``source_size``: the frame's (width, height) in source pixels."""
    m = np.asarray(mask) > 0.5
    H, W = m.shape
    lines = edge_lines(crop, source_size)
    out = []
    for name in EDGES:
        at, inward = lines[name]
        size = H if name in ("top", "bottom") else W
        lo, hi = (at, at + reach) if inward > 0 else (at - reach, at)
        lo, hi = max(int(np.floor(lo)), 0), min(int(np.ceil(hi)), size)
        if hi <= lo:
            continue
        band = m[lo:hi] if name in ("top", "bottom") else m[:, lo:hi].T
        if band.any(axis=0).mean() >= min_share:
            out.append(name)
    return out


def near_edges(points: np.ndarray, crop: Crop, source_size: tuple[int, int], edges, margin: float) -> np.ndarray:
    """(K,) bool: which of the points (K,2), crop pixels (x, y), lie within ``margin`` crop pixels of
    one of the source frame's ``edges`` (names of ``EDGES``) or past it. A landmark the detector
    puts there for a person the edge cuts off is a guess (the knees of a photo cut at the knees
    come back at the frame's bottom row, with some confidence)."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    lines = edge_lines(crop, source_size)
    out = np.zeros(len(p), bool)
    for name in edges:
        at, inward = lines[name]
        c = p[:, 1] if name in ("top", "bottom") else p[:, 0]
        out |= (c - at) * inward < margin
    return out


def held_landmarks(points: np.ndarray, visibility: np.ndarray, crop: Crop, source_size: tuple[int, int], edges,
                   margin: float, below: float, near: np.ndarray | None = None) -> np.ndarray:
    """(K,) bool: the landmarks (``points`` (K,2) crop pixels, detector confidences ``visibility``
    (K,)) that the frame's cutting ``edges`` cut off for the fit's hold (``FitConfig.w_cut``): past
    an edge, or within ``margin`` crop pixels of it with a confidence below ``below`` -- the
    detector's guess for a knee out of the frame, put on its last row. A foot the photo shows at its
    edge, with confidence, is no guess (its limb is not held; it is left out of the fit all the same).
    ``near``: ``near_edges(points, crop, source_size, edges, margin)`` when the caller has it."""
    past = near_edges(points, crop, source_size, edges, 0.0)
    if near is None:
        near = near_edges(points, crop, source_size, edges, margin)
    return past | (near & (np.asarray(visibility, np.float64).reshape(-1) < below))
