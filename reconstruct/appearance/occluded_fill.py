"""Colours for the parts the images cover but never show: a photo's neck and throat. With the head
bent or level, the chin hides the throat and the torso's Gaussians draw the skin and the collar
below it, so the neck keeps fewer trusted Gaussians than the wrap fill needs (0-14 of 1,653 on
seven real photos) and took the nearest filled colour of any part, and the torso's front by the
neck took its band's colour -- the red-dress photo's collar, a red bib under the chin once the
walk lifts the head.

Here each Gaussian of those parts (``WrapFillConfig.occluded_parts``) that faces a training camera
(its surface normal within ``acos(min_cos)`` of the direction to it) and projects onto the
person's mask takes the median, over the frames, of the image's colour round its projection:
what the images show where it lies, whatever covers it there (the throat under the chin, a
turtleneck's white). The wrap fill gives them to the unseen front of those parts within
``occluded_reach`` of the neck, on parts never seen behind their centre; their back is left to
the fill's fallback."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..body.parts import PART_INDEX
from .cut_fill import FrameView

MIN_COS = 0.5  # facing the camera within 60 degrees


def _window_mean(image: np.ndarray, x: np.ndarray, y: np.ndarray, radius: int) -> np.ndarray:
    """(S,3): the mean of ``image`` over the (2 radius + 1)² pixels round each (x, y), clipped to
    the image."""
    h, w = image.shape[:2]
    acc = np.zeros((len(x), 3))
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            acc += image[np.clip(y + dy, 0, h - 1), np.clip(x + dx, 0, w - 1)]
    return acc / (2 * radius + 1) ** 2


def occluded_colors(parts: np.ndarray, frames: Iterable[tuple[FrameView, np.ndarray]], *,
                    part_names: tuple[str, ...], min_cos: float = MIN_COS, radius: int = 1) -> np.ndarray:
    """(N,3) float32, NaN but for the Gaussians of ``part_names`` (the finish gives
    ``WrapFillConfig.occluded_parts``) that faced a camera and projected onto the person in at
    least one frame: the per-channel median over those frames of the image's mean colour over the
    (2 ``radius`` + 1)² pixels round the projection (module docstring). ``parts``: (N,) part indices. ``frames``: (view, cos) pairs, ``cos`` (N,) the cosine
    between each Gaussian's surface normal and the direction to the frame's camera; read once."""
    parts = np.asarray(parts)
    out = np.full((len(parts), 3), np.nan, np.float32)
    wanted = np.isin(parts, [PART_INDEX[n] for n in part_names if n in PART_INDEX])
    if not wanted.any():
        return out
    idx = np.flatnonzero(wanted)
    samples: list[np.ndarray] = []
    for view, cos in frames:
        cos = np.asarray(cos, np.float64)
        if cos.shape != parts.shape:
            raise ValueError(f"occluded_colors: cos has shape {cos.shape}, the parts {parts.shape}")
        got = np.full((len(idx), 3), np.nan)
        ok = (view.inside() & (cos >= min_cos))[idx]
        x = np.floor(view.uv[idx[ok], 0]).astype(np.int64)
        y = np.floor(view.uv[idx[ok], 1]).astype(np.int64)
        on = view.mask[y, x] > 0.5
        rows = np.flatnonzero(ok)[on]
        got[rows] = _window_mean(np.asarray(view.image, np.float64), x[on], y[on], radius)
        samples.append(got)
    if samples:
        stack = np.stack(samples)
        some = np.isfinite(stack[..., 0]).any(0)
        out[idx[some]] = np.nanmedian(stack[:, some], axis=0)
    return out
