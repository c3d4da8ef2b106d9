"""A pattern that repeats round a tube, carried on round its unseen side by whole periods.

Why. A check or plaid that repeats round a garment repeats in the distance round it, so the back
of a coat continues the front's checks with their phase, not their mirror image. The wrap fill's
mirror step (``wrap_fill``, step 3) copies the front through the coronal plane, which keeps the
phase only for a pattern symmetric about it; on the coat scene of seed 1 (checks round the coat)
the back's checks came out shifted by up to half a period. The garment layer's columns are
uniform in angle round its tube (``garment_layer.build_garment_layer``), so a pattern periodic
round the garment is, nearly, periodic in the layer's columns too.

How, per tube of the layer's (rows, cols) grid, on the reliably seen Gaussians:

1. **The period.** For each shift ``p`` (fractional, in columns; the shifted row linearly
   interpolated, wrapping round the tube) the mean squared colour difference between the seen
   Gaussians and the seen ones ``p`` columns on, ``msd(p)``. A pattern of period ``P`` is alike a
   period on and unlike half a period on: the period is the ``P`` that maximises the contrast
   ``msd(P / 2) / msd(P)`` over ``P`` in [``FINEST``, cols / 4] (at least four repeats round
   the tube) -- the smallest peak of it with at least half the largest contrast, since whole
   multiples of the period have contrast too; none when that is under ``MIN_PERIOD`` -- refined to the ``P`` within 10 % of it that
   minimises the mean of ``msd(k P)``, k = 1..3 (whole periods on agree too: a sharper estimate
   than one period alone).
2. **Is it a pattern.** The contrast must be at least ``MIN_CONTRAST`` and ``msd(P / 2)`` at least
   ``MIN_VARIATION``. A solid garment or stripes round it (no change along the row) have no
   contrast; a photo's shading varies slowly along the row (alike nearby, unlike far off), so half
   a period on is more alike than a period on and the contrast is below 1. And the pattern must
   have been seen to repeat: seen pairs two periods apart (at least ``MIN_PAIRS``), more alike
   than half a period apart (``msd(2 P) < msd(P / 2)``). A photo of an open jacket sees the
   shirt between the flaps as one light band with cloth on either side, over less than two of
   any period: a shift of nearly the seen width pairs flap with flap (alike) and half of it
   shirt with flap (unlike), which alone reads as a period of ~23 columns, and carried round it
   painted the back with shirt-white stripes. Those pairs two periods apart must also be at least
   ``REPEAT_SHARE`` as many as the pairs half a period apart, which asks for a seen width of about
   three periods: a video of a one-colour coat seen over 39 columns (its front only) read a period
   of 17.6 columns from its button column and the open front's edges (the pairs two periods apart
   were 232, all on the two plain flanks, against 1,740 half a period apart), and carried the
   buttons round onto the back twice.
3. **The continuation.** Each unseen Gaussian of a row takes the colour (interpolated) ``k`` whole
   periods along the row, for the smallest ``k`` (either way round) that lands between two seen
   Gaussians of the same row.
"""

from __future__ import annotations

import numpy as np

# columns: a shorter period is too fine for the layer to carry (under 5 samples a period the
# linear reads blur it and the period's error adds up over many repeats: wide trousers seed 0's
# checks repeat every 3.7 columns round each leg, and carried round they lost 0.08 dB unseen)
MIN_PERIOD = 5.0
FINEST = 2.0  # columns: periods measured down to this, so that a finer pattern is not taken at a multiple
MIN_CONTRAST = 1.5  # msd(P/2) / msd(P): unlike half a period on, alike a period on
MIN_VARIATION = 0.01  # msd(P/2): an RMS colour difference of 0.1 (summed over RGB) along the row
MIN_PAIRS = 200  # seen pairs a shift must have to be measured
REPEAT_SHARE = 0.4  # seen pairs two periods apart, against those half a period apart: seen repeating
STEP = 0.05  # columns: the resolution of the period
# msd under this is alike (an RMS colour difference of 0.03 summed over RGB, under the noise of
# trained colours): the contrast of a noise-free pattern is not unbounded at whole multiples of
# its period, which would hide the fundamental (exact checks: ~60 at the period, 1e29 at three)
ALIKE = 1e-3


def _read_columns(C: int, p: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each of ``C`` columns round a tube, the two columns a read ``p`` columns on falls
    between (wrapping) and the weight of the second."""
    q = np.arange(C) + p
    lo = np.floor(q).astype(np.int64) % C
    return lo, (lo + 1) % C, q - np.floor(q)


def _shifted(colors: np.ndarray, seen: np.ndarray, p: float) -> tuple[np.ndarray, np.ndarray]:
    """``colors`` (R,C,3) read ``p`` columns on (linear, wrapping), and where that read is seen."""
    lo, hi, w = _read_columns(colors.shape[1], p)
    w = w[None, :, None]
    return colors[:, lo] * (1 - w) + colors[:, hi] * w, seen[:, lo] & seen[:, hi]


def shift_pairs(seen: np.ndarray, p: float) -> int:
    """The number of seen Gaussians whose read ``p`` columns on is seen too."""
    lo, hi, _ = _read_columns(seen.shape[1], p)
    return int((seen & seen[:, lo] & seen[:, hi]).sum())


def shift_msd(colors: np.ndarray, seen: np.ndarray, p: float) -> float:
    """Mean squared RGB difference (summed over channels) between the seen Gaussians and the seen
    ones ``p`` columns on; NaN with fewer than ``MIN_PAIRS`` pairs."""
    sh, ok = _shifted(colors, seen, p)
    ok = ok & seen
    if ok.sum() < MIN_PAIRS:
        return float("nan")
    return float(((colors - sh) ** 2).sum(-1)[ok].mean())


def tube_period(colors: np.ndarray, seen: np.ndarray) -> float | None:
    """The period (columns) of a pattern repeating round one tube (``colors`` (R,C,3), ``seen``
    (R,C) bool), or None when the seen rows show none (see the module docstring)."""
    colors = np.asarray(colors, np.float64)
    seen = np.asarray(seen, bool)
    C = colors.shape[1]
    if C / 4 < MIN_PERIOD or seen.sum() < MIN_PAIRS:
        return None
    cache: dict[float, float] = {}

    def msd(p: float) -> float:
        key = round(p / STEP) * STEP
        if key not in cache:
            cache[key] = shift_msd(colors, seen, key)
        return cache[key]

    periods = np.arange(FINEST, C / 4 + STEP / 2, STEP)
    contrast = np.zeros(len(periods))
    for i, P in enumerate(periods):
        a, b = msd(P / 2), msd(P)
        if np.isfinite(a) and np.isfinite(b) and a >= MIN_VARIATION:
            contrast[i] = a / max(b, ALIKE)
    if contrast.max() < MIN_CONTRAST:
        return None
    # the fundamental: whole multiples of the period have contrast too (on clean checks more than
    # the period itself), so the smallest peak of the contrast with at least half the best's
    peaks = [i for i in range(len(periods)) if contrast[i] >= max(MIN_CONTRAST, 0.5 * contrast.max())
             and contrast[i] >= contrast[max(i - 1, 0)] and contrast[i] >= contrast[min(i + 1, len(periods) - 1)]]
    best = float(periods[peaks[0]])
    if best < MIN_PERIOD:  # the pattern repeats finer than the layer can carry (its multiples too)
        return None

    def harmonic(P: float) -> float:
        vals = [msd(k * P) for k in (1, 2, 3) if k * P <= C / 2]
        vals = [v for v in vals if np.isfinite(v)]
        return float(np.mean(vals)) if vals else float("inf")

    candidates = np.arange(0.9 * best, 1.1 * best + STEP / 2, STEP)
    period = float(min(candidates, key=harmonic))
    # seen to repeat: pairs two periods apart were seen, and are more alike than half a period
    # apart (not only a light band between two alike flanks, seen over less than two periods: an
    # open jacket's shirt). Not ``MIN_CONTRAST``: the trained checks of the coat scene drift
    # against the layer's columns, and two periods on they are 1.4 times more alike, not 1.5
    twice = msd(2 * period)
    if not np.isfinite(twice) or msd(period / 2) <= twice:
        return None
    # and those pairs are not a few at the ends of a seen width under ~3 periods
    if shift_pairs(seen, 2 * period) < REPEAT_SHARE * shift_pairs(seen, period / 2):
        return None
    return period


def continue_round(colors: np.ndarray, seen: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """(colors (R,C,3) with the unseen Gaussians continued by whole periods along their row, done
    (R,C) bool: those continued). Unseen Gaussians of a row with no seen pair a whole number of
    periods away keep their colour and are not done."""
    colors = np.asarray(colors, np.float64)
    seen = np.asarray(seen, bool)
    R, C, _ = colors.shape
    out = colors.copy()
    done = np.zeros((R, C), bool)
    reach = int(np.ceil(C / period)) + 1
    for r in range(R):
        todo = np.flatnonzero(~seen[r])
        if len(todo) == 0 or not seen[r].any():
            continue
        for c in todo:
            for k in range(1, reach):
                for sign in (-1, 1):
                    q = c + sign * k * period
                    lo = int(np.floor(q)) % C
                    hi = (lo + 1) % C
                    if seen[r, lo] and seen[r, hi]:
                        w = q - np.floor(q)
                        out[r, c] = colors[r, lo] * (1 - w) + colors[r, hi] * w
                        done[r, c] = True
                        break
                if done[r, c]:
                    break
    return out, done


def continue_layer(colors: np.ndarray, seen: np.ndarray, grid_shape: tuple[int, int],
                   tubes: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The layer's Gaussians (row-major on ``grid_shape``; the columns ``tubes`` blocks side by side,
    each wrapping round itself): (colors (M,3), done (M,) bool), each tube continued by its own
    period where it shows one."""
    R, C = grid_shape
    colors = np.asarray(colors, np.float64)
    seen = np.asarray(seen, bool)
    if colors.shape != (R * C, 3) or seen.shape != (R * C,):
        raise ValueError(f"continue_layer: colours (M,3) and seen (M,) for a {R}x{C} grid, found "
                         f"{colors.shape} and {seen.shape}")
    if C % tubes:
        raise ValueError(f"continue_layer: {C} columns do not split into {tubes} tubes")
    out = colors.reshape(R, C, 3).copy()
    done = np.zeros((R, C), bool)
    s = seen.reshape(R, C)
    w = C // tubes
    for k in range(tubes):
        block = slice(k * w, (k + 1) * w)
        period = tube_period(out[:, block], s[:, block])
        if period is not None:
            out[:, block], done[:, block] = continue_round(out[:, block], s[:, block], period)
    return out.reshape(R * C, 3), done.reshape(R * C)
