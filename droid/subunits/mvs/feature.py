"""Lap-joint feature extraction from one DSP frame (thesis §5.4, Strauss's method).

Input: 240 stripe columns, one per row (negative = no stripe), as the DSP's
FIR filter leaves them in its 1-bit bitmap.  Output: the seam feature point
(x_mm, y_mm) and the surface roll [rad] in the sensor frame S, or ``None``
when the frame holds no feature (it is never guessed).

The steps, as sensor.exe does them (thesis §5.4), with the robustness the
simulated noise asks for:

1. *Histogram bound.*  A histogram of the column values shows where the
   stripe concentrates; the run of well-filled bins around the peak (gaps up
   to the largest accepted step) bounds the data, and rows outside it
   (spurious DSP detections) are dropped.
2. *Discontinuity.*  The first derivative over a fixed interval of k rows --
   here the difference of the medians of the k points after and the k points
   before each position, less the profile's overall (median) slope -- is
   largest at the step.
3. *Two lines.*  A straight line is fitted to each side, leaving out a guard
   band around the step: a robust start (median of long-baseline slopes),
   then least squares with iterative rejection of residuals beyond
   max(floor, 3 sigma_MAD).  Each side needs enough inliers, a high inlier
   fraction and a small residual; the two slopes must agree (a lap joint's
   surfaces are parallel); the common slope is their variance-weighted mean
   and gives the roll.
4. *Position.*  The step's row is where the profile crosses the midline
   between the two lines.  The feature is the foot of the step on the
   *lower* (farther) surface: the point where the step's square edge meets
   the lower line -- through the crossing when the laser sees the edge face,
   through the upper surface's visible edge when the edge overhangs it.  For
   an unrolled surface that is simply the lower line at the crossing row.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from droid.cli import BadInput
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.wire import COLUMNS, ROWS

MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution per median absolute deviation


@dataclass(frozen=True)
class FeatureParams:
    """Tuning of :func:`extract` (pixels are rows or columns as named)."""

    hist_bin_px: int = 16  # histogram bin width [columns]
    hist_min_count: int = 3  # a bin needs this many rows to extend the bound ...
    hist_peak_fraction: float = 0.05  # ... and this fraction of the peak bin's count
    min_step_mm: float = 0.8  # smallest step accepted as the lap joint [mm]
    max_step_mm: float = 6.0  # largest step accepted [mm]
    derivative_rows: int = 8  # interval k of the first derivative [rows]
    guard_rows: float = 4.0  # rows either side of the step left out of the line fits
    min_side_rows: int = 12  # inliers needed on each side
    min_inlier_fraction: float = 0.7  # of each side's rows within the histogram bound
    residual_floor_px: float = 2.0  # never reject residuals below this [columns]
    residual_sigmas: float = 3.0  # reject residuals beyond this many sigma_MAD
    max_rms_px: float = 2.5  # largest inlier residual RMS accepted [columns]
    max_roll_disagreement_rad: float = 0.1  # slopes of the two sides must agree
    fit_iterations: int = 6


@dataclass(frozen=True)
class Feature:
    """The seam feature in the sensor frame S (docs/mvs.md)."""

    x_mm: float  # depth of the feature point (+ = farther from the sensor)
    y_mm: float  # lateral position of the feature point
    roll_rad: float  # surface rotation about S's z (0 = surface perpendicular to x)
    row: float  # fractional row of the feature point
    column: float  # lower surface's fitted column at that row
    step_mm: float  # step height measured perpendicular to the surfaces
    rows_used: int  # inlier rows of the two line fits


@dataclass(frozen=True)
class _Line:
    a: float  # column at row 0
    b: float  # columns per row
    sxx: float  # sum of squared row deviations of the inliers
    rms: float  # inlier residual RMS [columns]
    mean_r: float
    mean_c: float
    inliers: int
    threshold: float  # final rejection threshold [columns]


def _fit_robust(r: np.ndarray, c: np.ndarray, p: FeatureParams) -> _Line | str:
    """Robust straight line c = a + b r (see the module docstring, step 3)."""
    n = len(r)
    if n < p.min_side_rows:
        return f"only {n} rows on one side of the step"
    half = n // 2
    slope = float(np.median((c[half:half * 2] - c[:half]) / (r[half:half * 2] - r[:half])))
    intercept = float(np.median(c - slope * r))
    mask = np.ones(n, bool)
    threshold = p.residual_floor_px
    for _ in range(p.fit_iterations):
        res = c - (intercept + slope * r)
        sigma = MAD_TO_SIGMA * float(np.median(np.abs(res[mask] - np.median(res[mask]))))
        threshold = max(p.residual_floor_px, p.residual_sigmas * sigma)
        new_mask = np.abs(res) <= threshold
        if new_mask.sum() < 2:
            return "no consistent line on one side of the step"
        rm, cm = r[new_mask], c[new_mask]
        mean_r, mean_c = rm.mean(), cm.mean()
        sxx = float(((rm - mean_r) ** 2).sum())
        if sxx == 0.0:
            return "degenerate line fit"
        slope = float(((rm - mean_r) * (cm - mean_c)).sum() / sxx)
        intercept = float(mean_c - slope * mean_r)
        if np.array_equal(new_mask, mask):
            break
        mask = new_mask
    mask = np.abs(c - (intercept + slope * r)) <= threshold
    inliers = int(mask.sum())
    if inliers < p.min_side_rows or inliers < p.min_inlier_fraction * n:
        return f"too few inliers on one side of the step ({inliers} of {n})"
    rm, cm = r[mask], c[mask]
    rms = float(np.sqrt(np.mean((cm - (intercept + slope * rm)) ** 2)))
    if rms > p.max_rms_px:
        return f"line residual {rms:.2f} px > {p.max_rms_px} px"
    mean_r = float(rm.mean())
    return _Line(intercept, slope, float(((rm - mean_r) ** 2).sum()), rms, mean_r,
                 float(cm.mean()), inliers, threshold)


def _histogram_bound(c: np.ndarray, calib: MvsCalibration, p: FeatureParams) -> np.ndarray:
    """Mask of the columns inside the stripe's concentration (step 1)."""
    bins = -(-COLUMNS // p.hist_bin_px)
    counts = np.bincount((c // p.hist_bin_px).astype(int), minlength=bins)
    peak = int(np.argmax(counts))
    threshold = max(p.hist_min_count, p.hist_peak_fraction * counts[peak])
    max_gap = math.ceil(p.max_step_mm / calib.depth_mm_per_column / p.hist_bin_px)
    bounds = []
    for step in (-1, 1):
        edge, misses, k = peak, 0, peak + step
        while 0 <= k < bins and misses <= max_gap:
            if counts[k] >= threshold:
                edge, misses = k, 0
            else:
                misses += 1
            k += step
        bounds.append(edge)
    lo, hi = bounds[0] * p.hist_bin_px, (bounds[1] + 1) * p.hist_bin_px
    return (c >= lo) & (c < hi)


def _discontinuity(r: np.ndarray, c: np.ndarray, p: FeatureParams) -> tuple[int, float]:
    """Index j of the first point after the step, and the detrended jump [columns] (step 2)."""
    k = p.derivative_rows
    trend = float(np.median((c[k:] - c[:-k]) / (r[k:] - r[:-k])))
    med_c = np.median(sliding_window_view(c, k), axis=1)
    med_r = np.median(sliding_window_view(r, k), axis=1)
    jump = (med_c[k:] - med_c[:-k]) - trend * (med_r[k:] - med_r[:-k])  # split at j = i + k
    size = np.abs(jump)
    best = int(np.argmax(size))
    # The median keeps the jump flat for a few positions around the true step:
    # take the middle of that plateau.
    plateau = (size >= 0.8 * size[best]) & (np.sign(jump) == np.sign(jump[best]))
    lo = hi = best
    while lo > 0 and plateau[lo - 1]:
        lo -= 1
    while hi < len(jump) - 1 and plateau[hi + 1]:
        hi += 1
    return (lo + hi) // 2 + k, float(jump[best])


def _crossing_row(r, c, line_a: _Line, line_b: _Line, slope: float, split_row: float,
                  window: float) -> float:
    """Row where the profile crosses the midline between the two lines (step 4)."""
    near = np.abs(r - split_row) <= window
    rw, cw = r[near], c[near]
    ca, cb = line_a.mean_c + slope * (rw - line_a.mean_r), line_b.mean_c + slope * (rw - line_b.mean_r)
    tol = max(line_a.threshold, line_b.threshold)
    between = (cw >= np.minimum(ca, cb) - tol) & (cw <= np.maximum(ca, cb) + tol)
    rw, g = rw[between], (cw - (ca + cb) / 2)[between]
    side_a = np.sign(np.mean(ca - cb))
    if len(rw) < 2 or side_a == 0:
        return split_row
    # Split position m agreeing best with "side A before, side B after".
    before = np.concatenate([[0], np.cumsum(np.sign(g) == side_a)])
    after = np.concatenate([np.cumsum((np.sign(g) == -side_a)[::-1])[::-1], [0]])
    score = before + after
    ties = np.flatnonzero(score == score.max())
    m = int(ties[len(ties) // 2])
    if m == 0 or m == len(rw):
        return split_row
    r1, g1, r2, g2 = rw[m - 1], g[m - 1], rw[m], g[m]
    if g1 * side_a > 0 and g2 * side_a < 0:
        return float(r1 + g1 / (g1 - g2) * (r2 - r1))
    return float((r1 + r2) / 2)


def analyse(rows, calib: MvsCalibration, params: FeatureParams = FeatureParams()) -> Feature | str:
    """Like :func:`extract`, but says why a frame holds no feature (a reason string)."""
    p = params
    cols = np.asarray(rows)
    if cols.shape != (ROWS,):
        raise BadInput(f"a frame has {ROWS} rows, got shape {cols.shape}")
    r_all = np.arange(ROWS, dtype=float)
    ok = (cols >= 0) & (cols < COLUMNS)
    if ok.sum() < 2 * p.min_side_rows:
        return f"only {int(ok.sum())} rows with a stripe"
    c, r = cols[ok].astype(float), r_all[ok]
    keep = _histogram_bound(c, calib, p)
    c, r = c[keep], r[keep]
    if len(c) < 2 * p.min_side_rows:
        return f"only {len(c)} rows inside the histogram bound"

    j, jump = _discontinuity(r, c, p)
    min_step_px = p.min_step_mm / calib.depth_mm_per_column
    if abs(jump) < min_step_px:
        return f"no step (largest jump {abs(jump):.1f} px < {min_step_px:.1f} px)"
    split_row = (r[j - 1] + r[j]) / 2
    line_a = _fit_robust(r[r < split_row - p.guard_rows], c[r < split_row - p.guard_rows], p)
    if isinstance(line_a, str):
        return line_a
    line_b = _fit_robust(r[r > split_row + p.guard_rows], c[r > split_row + p.guard_rows], p)
    if isinstance(line_b, str):
        return line_b

    roll_a, roll_b = calib.slope_to_roll(line_a.b), calib.slope_to_roll(line_b.b)
    ratio = calib.depth_mm_per_column / calib.lateral_mm_per_row
    sigma = ratio * math.hypot(line_a.rms / math.sqrt(line_a.sxx), line_b.rms / math.sqrt(line_b.sxx))
    if abs(roll_a - roll_b) > p.max_roll_disagreement_rad + 4.0 * sigma:
        return f"the two lines disagree (roll {roll_a:.3f} vs {roll_b:.3f} rad)"
    slope = (line_a.b * line_a.sxx + line_b.b * line_b.sxx) / (line_a.sxx + line_b.sxx)
    roll = calib.slope_to_roll(slope)
    # Column of each line at row 0, with the common slope.
    a0 = line_a.mean_c - slope * line_a.mean_r
    b0 = line_b.mean_c - slope * line_b.mean_r
    step_mm = abs(b0 - a0) * calib.depth_mm_per_column * math.cos(roll)
    if not p.min_step_mm <= step_mm <= p.max_step_mm:
        return f"step {step_mm:.2f} mm outside [{p.min_step_mm}, {p.max_step_mm}] mm"

    row_x = _crossing_row(r, c, line_a, line_b, slope, split_row, p.derivative_rows + p.guard_rows)
    lower0, upper0 = (a0, b0) if a0 > b0 else (b0, a0)  # larger column = farther = lower
    upper_toward_plus_y = 1.0 if a0 > b0 else -1.0  # side A has the smaller rows
    # Work in mm: lower line x = alpha + beta * y, surface normal n (away from the sensor).
    beta = -math.tan(roll)
    x_low_at_row0 = (lower0 - calib.column_at_origin) * calib.depth_mm_per_column
    alpha = x_low_at_row0 - beta * calib.lateral_of(0.0)
    y_c = float(calib.lateral_of(row_x))
    edge_visible = upper_toward_plus_y * math.sin(roll) < 0
    column_p = (lower0 + upper0) / 2 if edge_visible else upper0
    px = (column_p + slope * row_x - calib.column_at_origin) * calib.depth_mm_per_column
    t = (alpha + beta * y_c - px) * math.cos(roll)
    x_mm, y_mm = px + t * math.cos(roll), y_c + t * math.sin(roll)
    return Feature(x_mm=float(x_mm), y_mm=float(y_mm), roll_rad=float(roll),
                   row=float(calib.row_of(y_mm)), column=float(calib.column_of(x_mm)),
                   step_mm=float(step_mm), rows_used=line_a.inliers + line_b.inliers)


def extract(rows, calib: MvsCalibration, params: FeatureParams = FeatureParams()) -> Feature | None:
    """The lap-joint feature of one frame of 240 stripe columns, or None (invalid frame)."""
    result = analyse(rows, calib, params)
    return None if isinstance(result, str) else result
