"""Time: cut a clip to [start, end] seconds, resample it to a frame rate (slerp for rotations, lerp for
the root position) and optionally make it loop."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .clip import MotionClip
from .rotations import matrix_to_quat, quat_to_matrix, slerp


@dataclass(frozen=True)
class Sampled:
    """A clip's motion at the output frame times."""

    local_rotations: np.ndarray  # (T,J,3,3)
    root_positions: np.ndarray  # (T,3), file units and world axes
    fps: float
    times: np.ndarray  # (T,) seconds in the file's time
    notes: tuple[str, ...] = ()


def _interp(quats: np.ndarray, root: np.ndarray, src_fps: float, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T = quats.shape[0]
    x = np.clip(times * src_fps, 0.0, T - 1)
    i0 = np.floor(x).astype(np.int64)
    i0 = np.minimum(i0, T - 1)
    i1 = np.minimum(i0 + 1, T - 1)
    w = x - i0
    q = slerp(quats[i0], quats[i1], np.broadcast_to(w[:, None], quats[i0].shape[:-1]))
    r = root[i0] * (1.0 - w)[:, None] + root[i1] * w[:, None]
    return q, r


def sample(clip: MotionClip, fps: float | None = None, start: float | None = None, end: float | None = None,
           loop: bool = False, blend_s: float = 0.5) -> Sampled:
    """The clip at ``fps`` (default: its own) between ``start`` and ``end`` seconds (default: all).

    ``loop``: the frame at ``end`` is left out (it would repeat the first), the root's horizontal
    drift from start to end is removed linearly so the motion stays in place, and over the last
    ``blend_s`` seconds (at most a quarter of the clip) the joint rotations and the root height ease
    into the first frame's, so that playing the frames over and over has no jump.
    """
    notes = []
    duration = clip.duration
    out_fps = float(fps) if fps is not None else clip.fps
    if not (np.isfinite(out_fps) and out_fps > 0):
        raise ValueError(f"frame rate must be positive, found {fps}")
    t0 = 0.0 if start is None else float(start)
    t1 = duration if end is None else float(end)
    if t0 < 0 or t0 > duration:
        raise ValueError(f"start {t0:g} s is outside the clip (0 to {duration:g} s)")
    if t1 > duration + 1e-9:
        notes.append(f"end {t1:g} s is past the clip's end: cut at {duration:g} s")
        t1 = duration
    if t1 < t0:
        raise ValueError(f"end {t1:g} s is before start {t0:g} s")
    span = t1 - t0
    n = int(np.floor(span * out_fps + 1e-6)) + 1
    if loop and n > 1 and abs((n - 1) / out_fps - span) < 1e-6:
        n -= 1  # the last frame would equal the first once looped
    times = t0 + np.arange(n) / out_fps
    quats = matrix_to_quat(clip.local_rotations)
    q, root = _interp(quats, clip.root_positions, clip.fps, times)
    if loop and span > 0 and n > 2:
        q_end, root_end = _interp(quats, clip.root_positions, clip.fps, np.array([t1]))
        q_start, root_start = q[:1], root[:1]
        up = clip.world_to_body.T @ np.array([0.0, 0.0, 1.0])  # the file's up axis
        drift = (root_end - root_start)[0]
        horizontal = drift - (drift @ up) * up
        frac = (times - t0) / span
        root = root - frac[:, None] * horizontal
        window = min(blend_s, 0.25 * span)
        w = np.clip((times - (t1 - window)) / max(window, 1e-9), 0.0, 1.0)
        w = 0.5 - 0.5 * np.cos(np.pi * w)  # ease in
        # local rotation that takes the end pose onto the start pose, applied progressively
        delta = _qmul(_qconj(q_end[0]), q_start[0])  # (J,4)
        target = _qmul(q, np.broadcast_to(delta, q.shape))
        q = slerp(q, target, np.broadcast_to(w[:, None], q.shape[:-1]))
        vertical = (root_start - root_end)[0] @ up
        root = root + (w * vertical)[:, None] * up
        notes.append(f"looped: horizontal drift {np.linalg.norm(horizontal) * clip.metres_per_unit:.2f} m removed, "
                     f"last {window:.2f} s blended into the first frame")
    return Sampled(quat_to_matrix(q), root, out_fps, times, tuple(notes))


def _qconj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], -1)
