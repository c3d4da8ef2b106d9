"""A pattern that repeats round a tube, carried on round its unseen side by its period.

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
3. **The continuation: the seen rows folded by the period.** Each seen Gaussian has a phase
   round the period, ``(column / P) mod 1``. The seen colours are modelled as a row's offset plus
   a waveform of the phase (``_Fold``): the waveform is the kernel-weighted mean of the
   seen colours less their row's offset at that phase (a Gaussian kernel ``BANDWIDTH`` of a period
   wide), the offsets the mean of each row's colours less the waveform, alternated. Shared by every
   row of the tube, the waveform is the checks' up-and-down stripes, the offsets the
   round-the-tube stripes (checks are the sum of the two). A pattern whose phase moves from row to
   row (diagonal stripes) has no shared waveform; the rows then fold alone, with their
   neighbours' colours (``ROW_REACH`` rows either side, at half weight), when that predicts the
   seen colours, each left out, with under ``ROWS_MARGIN`` of the shared fold's error. A margin,
   not the better of the two: the rows alone follow the seen side's local shading and noise and
   predict it a little better even on checks (trousers seed 2's second leg: 0.066 against 0.069),
   but carried round the back the shared waveform scores higher (29.34 against 29.23 dB unseen
   at ×2); diagonal stripes give the rows alone a third to a sixteenth of the shared error.
   The period is refined first to the one within ``REFINE`` (15 %) of it whose fold predicts
   the seen colours best, left one out:
   the shift-based estimate reads between columns and was 10 % off on the trousers of seed 0
   (3.78 and 3.74 columns, against 3.44 and 3.48 by the fold and the garment's 3.43), and within
   3 % the refinement stopped at 3.85, which carried the checks round out of phase (29.79 → 29.27
   dB unseen at ×2; refined within 15 %, 29.92). Each unseen Gaussian of a row with a seen one
   takes its row's offset plus the waveform at its phase.

   Why a fold and not a read a whole number of periods on. The layer samples the pattern at
   fractional phases: checks repeating every 3.5 columns (the wide trousers') fall between two
   columns wherever they are read, and a linear read between them halves the contrast of a line
   a column wide. Folded, the rows' many samples fill the period at every phase, and the back
   takes the lines at full contrast. Measured on the trousers of seed 2 (Stage I, its finish run
   again, ``eval --scale 2``, unseen): not carried (the old 5-column floor) 28.76 dB, read a whole
   number of periods on 28.98, folded 29.34.
"""

from __future__ import annotations

import numpy as np

# columns: a shorter period is too fine for the layer to carry: under 2 samples a period it is
# past the grid's Nyquist limit, and near it the rows' phases do not fill the period. (With the
# old linear reads the floor was 5 columns: wide trousers seed 0's checks repeat every 3.7 columns
# round each leg, and read between two columns they lost 0.08 dB unseen. Folded, 3.5 is carried.)
MIN_PERIOD = 2.5
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
BANDWIDTH = 0.06  # the fold's kernel, in periods (sd of a Gaussian in phase)
ROW_REACH = 1  # rows either side that a row folding alone borrows from (at half weight)
# the rows fold alone when that predicts the seen colours with under this share of the shared error
ROWS_MARGIN = 0.5
REFINE = 0.15  # the period is refined within this share of it
REFINE_STEP = 0.0015  # share of the period: candidates this far apart
PHASE_BINS = 512  # the fold's sums are taken on this many bins of the phase
FOLD_SWEEPS = 3  # alternations of the row offsets and the waveform


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


def _phases(C: int, period: float) -> np.ndarray:
    """Each of ``C`` columns' phase round ``period``, in [0, 1)."""
    return (np.arange(C) / period) % 1.0


def _kernel(d: np.ndarray) -> np.ndarray:
    """The fold's kernel at phase differences ``d`` (already taken round the circle)."""
    return np.exp(-0.5 * (d / BANDWIDTH) ** 2)


def _phase_kernel(bins: int) -> np.ndarray:
    """The fold's kernel on ``bins`` bins of the phase (circular, centred on bin 0)."""
    d = np.arange(bins) / bins
    return _kernel(np.minimum(d, 1.0 - d))


def _circular(values: np.ndarray, kernel_fft: np.ndarray) -> np.ndarray:
    """``values`` (bins, k) convolved round the phase with the kernel (its FFT)."""
    return np.real(np.fft.ifft(np.fft.fft(values, axis=0) * kernel_fft[:, None], axis=0))


class _Fold:
    """The seen Gaussians of one tube at a period: row offsets and a waveform shared by the rows."""

    def __init__(self, colors: np.ndarray, seen: np.ndarray, period: float):
        self.rows, self.cols = np.nonzero(seen)
        self.x = colors[self.rows, self.cols]
        self.R = colors.shape[0]
        self.bin = np.minimum((_phases(colors.shape[1], period) * PHASE_BINS).astype(np.int64), PHASE_BINS - 1)
        self.seen_bin = self.bin[self.cols]
        kernel = _phase_kernel(PHASE_BINS)
        self.k0 = kernel[0]
        self.kernel_fft = np.fft.fft(kernel)
        self.counts = np.bincount(self.rows, minlength=self.R).astype(np.float64)
        # the kernel's weight at each bin: the samples' phases do not change between the sweeps
        self.den = _circular(np.bincount(self.seen_bin, minlength=PHASE_BINS).astype(np.float64)[:, None],
                             self.kernel_fft)
        self.offset = np.zeros((self.R, 3))
        self.wave = np.zeros((PHASE_BINS, 3))
        for _ in range(FOLD_SWEEPS):
            self._fit_wave()
            self._fit_offsets()
        self._fit_wave()

    def _fit_wave(self) -> None:
        self.res = self.x - self.offset[self.rows]
        s = np.zeros((PHASE_BINS, 3))
        np.add.at(s, self.seen_bin, self.res)
        self.num = _circular(s, self.kernel_fft)
        self.wave = self.num / np.maximum(self.den, 1e-12)

    def _fit_offsets(self) -> None:
        w = self.wave[self.seen_bin]
        acc = np.zeros((self.R, 3))
        np.add.at(acc, self.rows, self.x - w)
        self.offset = acc / np.maximum(self.counts, 1)[:, None]

    def loo_error(self) -> float:
        """Mean squared error (summed over RGB) of each seen colour predicted without itself."""
        b = self.seen_bin
        num = self.num[b] - self.k0 * self.res
        den = self.den[b] - self.k0
        ok = den[:, 0] > 1e-6
        pred = self.offset[self.rows] + num / np.maximum(den, 1e-12)
        return float(((pred - self.x) ** 2).sum(-1)[ok].mean()) if ok.any() else float("inf")

    def predict(self, row: int, cols: np.ndarray) -> np.ndarray:
        return self.offset[row] + self.wave[self.bin[cols]]


def _row_fold(colors: np.ndarray, seen: np.ndarray, phase: np.ndarray, r: int,
              targets: np.ndarray, leave_out: bool = False) -> np.ndarray:
    """A row folded alone (with its ``ROW_REACH`` neighbours' colours, moved to its own mean, at half
    weight): the colours at the columns ``targets``; ``leave_out``: each target (a seen column of
    the row) predicted without itself."""
    R = colors.shape[0]
    own = colors[r][seen[r]].mean(0)
    xs, ps, ws, cs = [], [], [], []
    for j in range(max(0, r - ROW_REACH), min(R, r + ROW_REACH + 1)):
        cj = np.flatnonzero(seen[j])
        if len(cj) == 0:
            continue
        xs.append(colors[j, cj] - colors[j, cj].mean(0) + own)
        ps.append(phase[cj])
        ws.append(np.full(len(cj), 1.0 if j == r else 0.5))
        cs.append(np.where(j == r, cj, -1))
    xs, ps, ws, cs = (np.concatenate(a) for a in (xs, ps, ws, cs))
    d = phase[targets][:, None] - ps[None, :]
    d = d - np.round(d)
    k = _kernel(d) * ws[None, :]
    if leave_out:
        k[targets[:, None] == cs[None, :]] = 0.0
    den = k.sum(1, keepdims=True)
    return np.where(den > 1e-6, k @ xs / np.maximum(den, 1e-12), own)


def _rows_loo_error(colors: np.ndarray, seen: np.ndarray, period: float) -> float:
    phase = _phases(colors.shape[1], period)
    err, n = 0.0, 0
    for r in range(colors.shape[0]):
        cols = np.flatnonzero(seen[r])
        if len(cols) < 2:
            continue
        pred = _row_fold(colors, seen, phase, r, cols, leave_out=True)
        err += float(((pred - colors[r, cols]) ** 2).sum())
        n += len(cols)
    return err / n if n else float("inf")


def _refined_fold(colors: np.ndarray, seen: np.ndarray, period: float) -> tuple[float, _Fold]:
    """The period within ``REFINE`` of ``period`` whose shared fold predicts the seen colours best,
    each left out, and that fold."""
    step = REFINE_STEP * period
    candidates = np.arange((1 - REFINE) * period, (1 + REFINE) * period + step / 2, step)
    best, best_fold, best_error = None, None, np.inf
    for p in candidates:  # the first of equal errors, as argmin; only the best fold kept
        fold = _Fold(colors, seen, p)
        error = fold.loo_error()
        if best is None or error < best_error:
            best, best_fold, best_error = float(p), fold, error
    return best, best_fold


def refine_period(colors: np.ndarray, seen: np.ndarray, period: float) -> float:
    """The period within ``REFINE`` of ``period`` whose shared fold predicts the seen colours best,
    each left out."""
    return _refined_fold(np.asarray(colors, np.float64), np.asarray(seen, bool), period)[0]


def continue_round(colors: np.ndarray, seen: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """(colors (R,C,3) with the unseen Gaussians continued by the fold at ``period`` (refined), done
    (R,C) bool: those continued). Unseen Gaussians of a row with no seen Gaussian keep their
    colour and are not done. See the module docstring, step 3."""
    colors = np.asarray(colors, np.float64)
    seen = np.asarray(seen, bool)
    R, C, _ = colors.shape
    out = colors.copy()
    done = np.zeros((R, C), bool)
    if not seen.any():
        return out, done
    period, shared = _refined_fold(colors, seen, period)
    by_rows = _rows_loo_error(colors, seen, period) < ROWS_MARGIN * shared.loo_error()
    phase = _phases(C, period)
    for r in range(R):
        todo = np.flatnonzero(~seen[r])
        if len(todo) == 0 or not seen[r].any():
            continue
        out[r, todo] = (_row_fold(colors, seen, phase, r, todo) if by_rows
                        else shared.predict(r, todo))
        done[r, todo] = True
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
