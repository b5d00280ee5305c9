"""Lap-joint feature extraction from one DSP frame (thesis §5.4, Strauss's method).

Input: 240 stripe columns, one per row (negative = no stripe), as the DSP's
FIR filter leaves them in its 1-bit bitmap.  Output: the seam feature point
(x_mm, y_mm) and the surface roll [rad] in the sensor frame S, or ``None``
when the frame holds no feature (it is never guessed).

The steps, as sensor.exe does them (thesis §5.4), with the robustness the
simulated noise asks for:

1. *Histogram bound.*  A histogram of the column values shows where the
   stripe concentrates; the run of filled bins around the peak (gaps up to
   the largest accepted step), with one bin of margin, bounds the data, and
   rows outside it (spurious DSP detections) are dropped.
2. *Discontinuity.*  The first derivative over a fixed interval of k rows --
   here the difference of the medians of the k points after and the k points
   before each position, less the profile's overall (median) slope -- is
   largest at the step.  If the lines fitted about the largest jump fail the
   checks below, the next largest (up to three) is tried.
3. *Two lines.*  A straight line is fitted to each side, leaving out a guard
   band around the step: a robust start (median of long-baseline slopes),
   then least squares with iterative rejection of residuals beyond
   max(floor, 3 sigma_MAD).  Each side needs enough inliers, a high inlier
   fraction and a small residual; the two slopes must agree (a lap joint's
   surfaces are parallel); the common slope is their variance-weighted mean
   and gives the roll.
4. *Position.*  The step's row is where the profile crosses from one line
   to the other (rows next to it must fit the right line, or the frame is
   invalid), at the midline between them.  The feature is the foot of the
   step on the *lower* (farther) surface: the point where the step's square edge meets
   the lower line -- through the crossing when the laser sees the edge face,
   through the upper surface's visible edge when the edge overhangs it.  For
   an unrolled surface that is simply the lower line at the crossing row.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import accumulate

import numpy as np

from droid.cli import BadInput
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.wire import COLUMNS, ROWS

MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution per median absolute deviation
_R_ALL = np.arange(ROWS, dtype=float)  # the row index of each of the 240 rows


# The medians below are np.median's values bit for bit (the same middle
# elements, their sum halved, -0.0 made +0.0 as np.mean does) without its
# per-call overhead (~30 us a call against ~2 us): the feature extraction
# takes some thirty medians per frame.  The inputs here are finite: no NaN
# handling.

def _median(a: np.ndarray) -> float:
    """Median of a 1-D float array of finite values, exactly as ``float(np.median(a))``.

    Reorders ``a`` in place: pass a temporary (or a copy).
    """
    n = a.shape[0]
    h = n >> 1
    if n & 1:
        a.partition(h)
        return float(a[h]) + 0.0
    a.partition((h - 1, h))
    return (float(a[h - 1]) + float(a[h]) + 0.0) / 2


def _windows(a: np.ndarray, width: int) -> np.ndarray:
    """(len - width + 1, width) view of the sliding windows of a 1-D contiguous float array."""
    return np.ndarray((a.shape[0] - width + 1, width), dtype=a.dtype, buffer=a, strides=(a.strides[0],) * 2)


def _median_rows(w: np.ndarray) -> np.ndarray:
    """Median of each row of a 2-D array of finite values, exactly as ``np.median(w, axis=1)``.

    A sort of the short rows is cheaper than np.partition along them.
    """
    m = w.shape[1]
    h = m >> 1
    s = np.sort(w, axis=1)
    if m & 1:
        return s[:, h] + 0.0
    return (s[:, h - 1] + s[:, h] + 0.0) / 2


def _running_median5(c: np.ndarray) -> np.ndarray:
    """Median of each 5 consecutive values of a 1-D array (len - 4 of them), exactly.

    A selection network of minima and maxima (6 exchanges, then the median
    of three): it returns an input value, as np.median of 5 does.
    """
    n = c.shape[0] - 4
    mn, mx = np.minimum, np.maximum
    a0, a1, a3, a4 = c[0:n], c[1:n + 1], c[3:n + 3], c[4:n + 4]
    lo = mx(mn(a0, a1), mn(a3, a4))  # the larger of the two pairs' minima
    hi = mn(mx(a0, a1), mx(a3, a4))  # the smaller of the two pairs' maxima
    return mx(mn(lo, hi), mn(mx(lo, hi), c[2:n + 2])) + 0.0


# Deliberate copy: tests/mvs/feature_reference.py keeps this module as it was before the speed work,
# the reference the tests hold this one to bit for bit -- change the logic here, never there.
@dataclass(frozen=True)
class FeatureParams:
    """Tuning of :func:`extract` (pixels are rows or columns as named)."""

    hist_bin_px: int = 16  # histogram bin width [columns]
    hist_min_count: int = 3  # a bin needs this many rows to extend the bound
    min_step_mm: float = 0.8  # smallest step accepted as the lap joint [mm]
    max_step_mm: float = 6.0  # largest step accepted [mm]
    derivative_rows: int = 8  # interval k of the first derivative [rows]
    prefilter_rows: int = 5  # running median before the derivative [rows, odd]
    guard_rows: float = 4.0  # rows either side of the step left out of the line fits
    min_side_rows: int = 12  # inliers needed on each side
    min_inlier_fraction: float = 0.7  # of each side's rows within the histogram bound
    residual_floor_px: float = 2.0  # never reject residuals below this [columns]
    residual_sigmas: float = 3.0  # reject residuals beyond this many sigma_MAD
    max_rms_px: float = 2.5  # largest inlier residual RMS accepted [columns]
    max_roll_disagreement_rad: float = 0.1  # slopes of the two sides must agree
    min_support_rows: int = 4  # rows on each line next to the step
    max_misfit_rows: int = 2  # rows of the wrong line on the wrong side of the step
    max_gap_rows: float = 3.0  # unexplained rows allowed between the two lines' last rows
    max_candidates: int = 3  # jumps tried, largest first
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
    slope = _median((c[half:half * 2] - c[:half]) / (r[half:half * 2] - r[:half]))
    intercept = _median(c - slope * r)
    mask = None  # all rows
    threshold = p.residual_floor_px
    add = np.add.reduce  # = ndarray.sum / mean's sum (pairwise), without the method overhead
    new_mask = None
    for _ in range(p.fit_iterations):
        res = c - (intercept + slope * r)
        kept = res.copy() if mask is None else res[mask]
        sigma = MAD_TO_SIGMA * _median(np.abs(kept - _median(kept)))  # kept's order does not matter
        threshold = max(p.residual_floor_px, p.residual_sigmas * sigma)
        new_mask = np.abs(res) <= threshold
        count = int(np.count_nonzero(new_mask))
        if count < 2:
            return "no consistent line on one side of the step"
        rm, cm = r[new_mask], c[new_mask]
        mean_r, mean_c = float(add(rm)) / count, float(add(cm)) / count
        dr = rm - mean_r
        sxx = float(add(dr * dr))
        if sxx == 0.0:
            return "degenerate line fit"
        slope = float(add(dr * (cm - mean_c))) / sxx
        intercept = mean_c - slope * mean_r
        if count == n if mask is None else new_mask.tobytes() == mask.tobytes():
            break
        mask = new_mask
    mask = np.abs(c - (intercept + slope * r)) <= threshold
    inliers = int(np.count_nonzero(mask))
    if inliers < p.min_side_rows or inliers < p.min_inlier_fraction * n:
        return f"too few inliers on one side of the step ({inliers} of {n})"
    if new_mask is None or mask.tobytes() != new_mask.tobytes():  # else: the last fit's rows, means, sxx
        rm, cm = r[mask], c[mask]
        mean_r, mean_c = float(add(rm)) / inliers, float(add(cm)) / inliers
        dr = rm - mean_r
        sxx = float(add(dr * dr))
    e = cm - (intercept + slope * rm)
    rms = math.sqrt(float(add(e * e)) / inliers)
    if rms > p.max_rms_px:
        return f"line residual {rms:.2f} px > {p.max_rms_px} px"
    return _Line(slope, sxx, rms, mean_r, mean_c, inliers, threshold)


def _histogram_bound(c: np.ndarray, calib: MvsCalibration, p: FeatureParams) -> np.ndarray:
    """Mask of the columns inside the stripe's concentration (step 1)."""
    bins = -(-COLUMNS // p.hist_bin_px)
    counts = np.bincount((c // p.hist_bin_px).astype(int), minlength=bins)
    peak = int(counts.argmax())
    counts = counts.tolist()
    threshold = p.hist_min_count
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
    # One bin of margin keeps the sparse ends of the stripe itself.
    lo, hi = (bounds[0] - 1) * p.hist_bin_px, (bounds[1] + 2) * p.hist_bin_px
    return (c >= lo) & (c < hi)


def _discontinuities(r: np.ndarray, c: np.ndarray, min_jump_px: float, max_jump_px: float,
                     p: FeatureParams) -> list[tuple[int, float]]:
    """Candidate steps, largest first: (index j of the first point after, jump [columns]) (step 2).

    ``r`` ascending (the rows in order), ``c`` their columns.
    The jump at each position is the median of the k points after less the
    median of the k points before (of the profile after a short running
    median), less the profile's median slope over k.
    The median keeps the jump flat for a few positions around a step; a
    candidate is the middle of that plateau.  Candidates are separated by at
    least k points and must exceed ``min_jump_px``.
    """
    k = p.derivative_rows
    trend = _median((c[k:] - c[:-k]) / (r[k:] - r[:-k]))
    half = p.prefilter_rows // 2  # a running median first removes isolated spurious rows
    padded = np.concatenate((c[:1].repeat(half), c, c[-1:].repeat(half)))  # np.pad(mode="edge")
    c = _running_median5(padded) if half == 2 else _median_rows(_windows(padded, 2 * half + 1))
    med_c = _median_rows(_windows(c, k))
    # r is in row order, so each window of r is sorted: its median is its middle
    m, h = len(r) - k + 1, k // 2
    med_r = r[h:h + m] + 0.0 if k % 2 else (r[h - 1:h - 1 + m] + r[h:h + m] + 0.0) / 2
    jump = (med_c[k:] - med_c[:-k]) - trend * (med_r[k:] - med_r[:-k])  # split at j = i + k
    size = np.abs(jump)
    candidates = []
    size[size > max_jump_px] = 0.0  # more than any step: spurious rows
    while len(candidates) < p.max_candidates:
        best = int(size.argmax())
        size_best = float(size[best])
        if size_best < min_jump_px:
            break
        jump_best = float(jump[best])  # > 0 or < 0: np.sign(jump) == np.sign(jump_best) is the same test
        plateau = ((size >= 0.8 * size_best) & ((jump > 0) if jump_best > 0 else (jump < 0))).tolist()
        lo = hi = best
        while lo > 0 and plateau[lo - 1]:
            lo -= 1
        while hi < len(plateau) - 1 and plateau[hi + 1]:
            hi += 1
        candidates.append(((lo + hi) // 2 + k, jump_best))
        size[max(0, lo - k):hi + k + 1] = 0.0
    return candidates


def _locate_step(r: np.ndarray, c: np.ndarray, a0: float, b0: float, slope: float,
                 tol: tuple[float, float], split_row: float, edge_visible: bool,
                 max_gap_rows: float, p: FeatureParams) -> float | str:
    """Fractional row where the profile crosses from line A to line B (step 4).

    Rows within ``tol`` of exactly one line are classified A or B; the split
    agreeing best with "A before, B after" (near the coarse split) gives the
    last A row and the first B row.  Between them the crossing of the
    midline is interpolated over the edge-face rows when the laser sees the
    edge; otherwise (edge hidden or seen edge-on) it is their midpoint.
    A split without clean support on both sides is no step.
    """
    window = p.derivative_rows + p.guard_rows
    near = np.abs(r - split_row) <= window
    # The ~25 rows near the split, in plain floats: the same arithmetic, row by row.
    rows = []  # (row, column, line A's column, line B's column, on A, on B)
    ra, is_a = [], []  # the rows on exactly one line, and whether that is A
    tol_a, tol_b = tol
    for x, y in zip(r[near].tolist(), c[near].tolist()):
        u, v = a0 + slope * x, b0 + slope * x
        oa, ob = abs(y - u) <= tol_a, abs(y - v) <= tol_b
        rows.append((x, y, u, v, oa, ob))
        if oa != ob:
            ra.append(x)
            is_a.append(oa)
    if len(ra) < 2:
        return "step not located (no rows near it fit the lines)"
    before_a = [0, *accumulate(is_a)]  # A rows before each split
    after_b = [*accumulate([not a for a in reversed(is_a)])][::-1] + [0]  # B rows after each split
    score = [a + b for a, b in zip(before_a, after_b)]
    top = max(score)
    ties = [i for i, v in enumerate(score) if v == top]
    m = ties[len(ties) // 2]
    if m == 0 or m == len(ra):
        return "step not located (one side has no rows near it)"
    wrong = len(ra) - score[m]
    if before_a[m] < p.min_support_rows or after_b[m] < p.min_support_rows or wrong > p.max_misfit_rows:
        return "step not located (the lines do not meet there)"
    r_a, r_b = ra[m - 1], ra[m]
    if r_b - r_a > max_gap_rows:
        return f"step not located (a gap of {r_b - r_a:.0f} rows)"
    if not edge_visible:
        return (r_a + r_b) / 2
    rf, g = [], []  # the edge face's rows and their distance from the midline
    for x, y, u, v, oa, ob in rows:
        inside = min(u, v) < y < max(u, v)  # spurious rows lie outside
        if r_a <= x <= r_b and (x == r_a or x == r_b or (inside and not (oa or ob))):
            rf.append(x)
            g.append(y - (u + v) / 2)
    sign_a = math.copysign(1.0, a0 - b0)
    for k in range(1, len(rf)):
        if g[k] * sign_a <= 0 < g[k - 1] * sign_a:
            return rf[k - 1] + g[k - 1] / (g[k - 1] - g[k]) * (rf[k] - rf[k - 1])
    return (r_a + r_b) / 2


def analyse(rows, calib: MvsCalibration, params: FeatureParams = FeatureParams()) -> Feature | str:
    """Like :func:`extract`, but says why a frame holds no feature (a reason string)."""
    p = params
    cols = np.asarray(rows)
    if cols.shape != (ROWS,):
        raise BadInput(f"a frame has {ROWS} rows, got shape {cols.shape}")
    ok = (cols >= 0) & (cols < COLUMNS)
    n_ok = int(np.count_nonzero(ok))
    if n_ok < 2 * p.min_side_rows:
        return f"only {n_ok} rows with a stripe"
    c, r = cols[ok].astype(float), _R_ALL[ok]
    keep = _histogram_bound(c, calib, p)
    c, r = c[keep], r[keep]
    if len(c) < 2 * p.min_side_rows:
        return f"only {len(c)} rows inside the histogram bound"

    min_step_px = p.min_step_mm / calib.depth_mm_per_column
    # A rolled step shows a vertical jump of step / cos(roll); allow rolls to 60 deg.
    candidates = _discontinuities(r, c, min_step_px, 2.0 * p.max_step_mm / calib.depth_mm_per_column, p)
    if not candidates:
        return f"no step (no jump of {min_step_px:.1f} px or more)"
    # The largest jump is the step unless the lines say otherwise; then the
    # next largest is tried (spurious rows can make a jump of their own).
    first_reason = ""
    for j, _ in candidates:
        result = _feature_at((r[j - 1] + r[j]) / 2, r, c, calib, p)
        if isinstance(result, Feature):
            return result
        first_reason = first_reason or result
    return first_reason


def _feature_at(split_row: float, r: np.ndarray, c: np.ndarray, calib: MvsCalibration,
                p: FeatureParams) -> Feature | str:
    """Steps 3 and 4 for the step near ``split_row``: the feature, or why there is none."""
    side = r < split_row - p.guard_rows
    line_a = _fit_robust(r[side], c[side], p)
    if isinstance(line_a, str):
        return line_a
    side = r > split_row + p.guard_rows
    line_b = _fit_robust(r[side], c[side], p)
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

    lower0, upper0 = (a0, b0) if a0 > b0 else (b0, a0)  # larger column = farther = lower
    upper_toward_plus_y = 1.0 if a0 > b0 else -1.0  # side A has the smaller rows
    edge_visible = upper_toward_plus_y * math.sin(roll) < 0
    face_rows = step_mm * abs(math.sin(roll)) / calib.lateral_mm_per_row
    row_x = _locate_step(r, c, a0, b0, slope, (line_a.threshold, line_b.threshold), split_row,
                         edge_visible, 1.0 + face_rows + p.max_gap_rows, p)
    if isinstance(row_x, str):
        return row_x
    # Work in mm: lower line x = alpha + beta * y, surface normal n (away from the sensor).
    beta = -math.tan(roll)
    x_low_at_row0 = (lower0 - calib.column_at_origin) * calib.depth_mm_per_column
    alpha = x_low_at_row0 - beta * calib.lateral_of(0.0)
    y_c = float(calib.lateral_of(row_x))
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
