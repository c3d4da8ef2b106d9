"""How far a one-tube garment layer must reach sideways, row by row, to meet the masks.

The layer's rings are the body's hull plus a standoff that grows from the top to the hem alike all
round (``build_garment_layer``): a skirt swung to one side in a photo, or a coat cut wider than the
flare read just above its hem, stands past them on one side. Offsets are bounded, so training
cannot carry the layer out there, and the cloth's share of the mask stays a hole.

``frame_side_reach`` poses the layer in a front-view frame and, for each row and each side of the
body, reads how far the mask's edge lies past the row's outermost projected point (or past the
posed body's own silhouette there, when an arm or a hand reaches further): in the image row of that
point, the mask run round the ring's projected centre, its end on that side, in metres at the
point's depth (negative where the ring stands past the mask). ``fit_side_profile`` takes the
median over the frames and stretches each ring's half on that side by it
(``VolumeHint.side_profile``, ``VolumeHint.side_reach``), reading again after each stretch: a body
turned from the camera moves the ring's edge in the image by less than the stretch. Only a side
that must reach out ``MIN_SIDE_REACH`` (10 cm) or more somewhere is stretched: smaller gaps are
left to the Gaussians' learned offsets. A walk whose skirt swings both ways gives medians near 0;
the synthetic benchmark's symmetric garments read under 1 cm and keep their layers as they were.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..body.base import BodyModel
from .garment_layer import (GARMENT_LAYER_STEP, GarmentLayer, VolumeHint, _run_around, body_silhouette,
                            build_garment_layer, spread_frames)
from .config import ONE_TUBE_FILTER

# metres a side must reach past the rings somewhere to be stretched: smaller gaps are left to the
# Gaussians' learned offsets (stretched by 3-7 cm, the green-coat and green-jacket photos fitted
# worse, alpha IoU 0.931 -> 0.900 and 0.927 -> 0.910; by 19-32 cm, the swung skirts much better)
MIN_SIDE_REACH = 0.10
MAX_SIDE_REACH = 0.40  # metres: no ring is stretched further
MIN_GAIN = 0.3  # a row's stretch must move the ring's edge in the image by this share of itself to be kept


def frame_side_reach(body: BodyModel, layer: GarmentLayer, frame, silhouette: np.ndarray | None = None) -> np.ndarray:
    """(rows, 2) metres the mask reaches past each row of the one-tube ``layer`` posed in ``frame``
    on the body's left (+X, column 0) and right (column 1); NaN where the row's outermost point
    falls off the image or the mask has no run round the ring's centre (see the module docstring).
    ``silhouette``: the posed body's own (``body_silhouette``), when the caller has it."""
    if layer.tubes != 1:
        raise ValueError(f"side reach: needs a one-tube layer, found {layer.tubes} tubes")
    R, C = layer.grid_shape
    P = layer.posed(body, frame.pose)[0].numpy()
    uv, depth = frame.camera.project(P)
    uv, depth = uv.reshape(R, C, 2), depth.reshape(R, C)
    L = body.bone_labels
    J = body.posed_joints(frame.pose).numpy()
    hips_x = frame.camera.project(J[[L.index("upperleg01.L"), L.index("upperleg01.R")]])[0][:, 0]
    towards_left = 1.0 if hips_x[0] >= hips_x[1] else -1.0  # image x direction of the body's +X
    mask = np.asarray(frame.mask) > 0.5
    sil = body_silhouette(body, frame) if silhouette is None else silhouette
    H = mask.shape[0]
    out = np.full((R, 2), np.nan)
    for r in range(R):
        if not (np.isfinite(uv[r]).all() and (depth[r] > 0).all()):
            continue
        centre = int(round(float(uv[r, :, 0].mean())))
        for k, sgn in enumerate((towards_left, -towards_left)):
            c = int(np.argmax(uv[r, :, 0] * sgn))
            row = int(round(float(uv[r, c, 1])))
            if not 0 <= row < H:
                continue
            run = _run_around(mask[row], centre)
            if run is None:
                continue
            end = run[1] if sgn > 0 else run[0]
            inside = np.flatnonzero(sil[row, run[0]:run[1] + 1]) + run[0]
            edge = float(uv[r, c, 0]) * sgn
            if len(inside):
                edge = max(edge, float(inside.max() if sgn > 0 else inside.min()) * sgn)
            out[r, k] = (end * sgn - edge) * float(depth[r, c]) / float(frame.camera.fx)
    return out


def fit_side_profile(body: BodyModel, hint: VolumeHint, frames, *, row_step: float = GARMENT_LAYER_STEP,
                     max_frames: int = 8, iterations: int = 3, min_reach: float = MIN_SIDE_REACH,
                     max_reach: float = MAX_SIDE_REACH, min_gain: float = MIN_GAIN,
                     smooth_rows: float = 1.0, layer: GarmentLayer | None = None,
                     silhouettes: list | None = None, one_tube_filter: float = ONE_TUBE_FILTER) -> VolumeHint:
    """``hint`` with the ``side_profile`` that stretches its one-tube layer out to the masks of up to
    ``max_frames`` of ``frames`` spread evenly over the sequence; ``hint`` itself when neither side
    reaches ``min_reach`` anywhere, and for two-tube layers (trousers).

    A row's need is the median of ``frame_side_reach`` over the frames that read it (0 when fewer
    than half do). It is added to the profile (smoothed over ``smooth_rows`` rows; where the row is
    not stretched yet, its positive part only; never below 0), the layer rebuilt and read again,
    ``iterations`` times: a stretch in the body's x moves the ring's edge in the image by more or
    less than itself when the body is turned from the camera. A row whose step moved its edge by
    less than ``min_gain`` of itself (a ring crumpled by crossed legs, whose outermost point
    belongs to the other leg) keeps the profile it had before and is not changed again. Reaches
    are clipped to ``max_reach``; a side that stays under ``min_reach`` is 0.

    ``layer``: ``hint``'s own layer, and ``silhouettes``: the posed body's in the frames
    ``spread_frames`` picks, when the caller has them (``garment_layer_for``); ``one_tube_filter``:
    the layers it builds are built with it (``build_garment_layer``)."""
    if hint.two_legs or not len(frames):
        return hint
    picked = spread_frames(frames, max_frames)
    sils = silhouettes if silhouettes is not None else [body_silhouette(body, f) for f in picked]

    def need(h: VolumeHint, built: GarmentLayer | None = None) -> tuple[GarmentLayer, np.ndarray]:
        if built is None:
            built = build_garment_layer(body, h, row_step=row_step, one_tube_filter=one_tube_filter)
        reads = np.stack([frame_side_reach(body, built, f, s) for f, s in zip(picked, sils, strict=True)])
        seen = np.isfinite(reads)  # (F,R,2)
        med = np.nanmedian(np.where(seen.any(0), reads, 0.0), axis=0)  # rows no frame reads: 0, no warning
        return built, np.where(seen.sum(0) * 2 >= len(picked), med, 0.0)

    base = replace(hint, side_profile=())
    layer, now = need(base, None if hint.side_profile else layer)
    R = len(now)
    zs = layer.positions.numpy().reshape(R, -1, 3)[:, :, 2].mean(1)
    profile = np.zeros((R, 2))
    frozen = np.zeros((R, 2), bool)
    knots = lambda p: tuple((float(z), float(a), float(b)) for z, (a, b) in zip(zs, p))  # noqa: E731
    for it in range(iterations):
        # out where the mask reaches past the ring; back in where a stretch overshot, not past 0
        step = gaussian_filter1d(np.where(profile > 0, now, np.clip(now, 0.0, None)), smooth_rows, axis=0,
                                 mode="nearest")
        step = np.where(frozen, 0.0, np.clip(step, -profile, max_reach - profile))
        if it == 0 and step.max() < min_reach:
            return hint
        if np.abs(step).max() < 0.005:
            break
        trial = profile + step
        after = need(replace(base, side_profile=knots(trial)))[1]
        moved = (now - after) * np.sign(step)  # how far the edge went the way the stretch did
        weak = (np.abs(step) > 0.005) & (moved < min_gain * np.abs(step))
        frozen |= weak
        profile = np.where(weak, profile, trial)
        now = np.where(weak, now, after)
    profile[:, profile.max(0) < min_reach] = 0.0
    return replace(hint, side_profile=knots(profile) if profile.any() else ())
