"""Twin of the MVS laser/camera and its DSP board's FIR output (thesis §2.5, §5.3).

The laser sheet is the sensor frame S's x-y plane; x is depth (along the
laser's projection, + = away from the sensor), y lateral, z the travel
direction (docs/mvs.md).  Rows are lines of constant y; along each the laser
is modelled as a ray parallel to +x from ``standoff_mm`` in front of the
measuring point (a telecentric sheet).  The first workpiece surface the ray
meets -- upper surface, the step's square edge face, or lower surface --
is where the stripe lies; its depth maps to a column through the linear
calibration:

    row    = row_at_origin    + y_mm / lateral_mm_per_row
    column = column_at_origin + x_mm / depth_mm_per_column

The DSP's FIR filter leaves one pixel per row in a 1-bit bitmap, so the
columns are integers (rounded after Gaussian sub-pixel jitter); a row with no
surface, or one outside the 512 columns, holds -1.  A fraction of rows can be
replaced by spurious detections at random columns, and a whole frame can be
dropped (``frame`` returns None).  Everything is a pure function of the pose
and the numpy Generator passed in.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from droid.sim.mvs.frames import apply
from droid.sim.workpiece import Workpiece
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.wire import COLUMNS, FRAME_RATE_HZ, NO_STRIPE, ROWS

__all__ = ["CameraNoise", "MvsCalibration", "MvsCamera", "FRAME_RATE_HZ",
           "lap_joint_profile_mm", "quantise"]


@dataclass(frozen=True)
class CameraNoise:
    """Noise of the camera and DSP filter."""

    jitter_px: float = 0.0  # sigma of Gaussian sub-pixel jitter of each stripe column [px]
    spurious_fraction: float = 0.0  # probability a row holds a random column instead
    drop_probability: float = 0.0  # probability a frame is not delivered

    def __post_init__(self) -> None:
        if not (self.jitter_px >= 0 and 0 <= self.spurious_fraction <= 1 and 0 <= self.drop_probability <= 1):
            raise ValueError(f"bad camera noise {self}")


def quantise(depth_mm: np.ndarray, calib: MvsCalibration, noise: CameraNoise,
             rng: np.random.Generator) -> np.ndarray | None:
    """Depths x [mm] per row (NaN = no stripe) -> the DSP's int16 columns, or None if dropped.

    Draws the same count of random numbers every call, so a seeded run is
    reproducible whatever the frames hold.
    """
    dropped = rng.random() < noise.drop_probability
    jitter = rng.standard_normal(ROWS) * noise.jitter_px
    spurious = rng.random(ROWS) < noise.spurious_fraction
    random_cols = rng.integers(0, COLUMNS, ROWS)
    if dropped:
        return None
    col = np.rint(calib.column_of(np.asarray(depth_mm, float)) + jitter)
    stripe = (col >= 0) & (col < COLUMNS)  # False for NaN (no stripe) and +-inf
    out = np.where(stripe, col, NO_STRIPE).astype(np.int16)
    out[spurious] = random_cols[spurious]
    return out


def lap_joint_profile_mm(calib: MvsCalibration, foot_x_mm: float, foot_y_mm: float,
                         roll_rad: float, step_mm: float, upper_side: float = 1.0) -> np.ndarray:
    """Ideal stripe depth x [mm] per row for a straight lap joint seen in S (NaN = none).

    A 2-D version of the camera for synthetic tests: the seam foot at
    (foot_x, foot_y), surfaces rolled by ``roll_rad`` (their direction in S is
    (-sin roll, cos roll)), the upper surface ``step_mm`` nearer the sensor on
    the side ``upper_side`` (+1 = toward +y when unrolled), a square edge.
    Surfaces are unbounded; a ray sees the nearest of upper surface, edge face
    and lower surface.
    """
    y = calib.lateral_of(np.arange(ROWS, dtype=float))
    v = np.array([-math.sin(roll_rad), math.cos(roll_rad)])  # along the surface (x, y)
    n = np.array([math.cos(roll_rad), math.sin(roll_rad)])  # normal, away from the sensor
    foot = np.array([foot_x_mm, foot_y_mm])
    top = foot - step_mm * n
    beta = -math.tan(roll_rad)  # dx/dy of both surfaces
    x_up = top[0] + beta * (y - top[1])
    x_low = foot[0] + beta * (y - foot[1])
    on_upper = upper_side * ((x_up - top[0]) * v[0] + (y - top[1]) * v[1]) >= 0
    on_lower = upper_side * ((x_low - foot[0]) * v[0] + (y - foot[1]) * v[1]) < 0
    candidates = [np.where(on_upper, x_up, np.inf), np.where(on_lower, x_low, np.inf)]
    if abs(top[1] - foot[1]) > 1e-12:  # the edge face, seen edge-on when unrolled
        frac = (y - foot[1]) / (top[1] - foot[1])
        candidates.append(np.where((frac >= 0) & (frac <= 1), foot[0] + frac * (top[0] - foot[0]), np.inf))
    x = np.min(candidates, axis=0)
    return np.where(np.isfinite(x), x, np.nan)


class MvsCamera:
    """The laser/camera/DSP twin over one workpiece (see the module docstring).

    Per frame it intersects the 240 rays with the two surface planes and
    finds the nearest seam point of each of the 480 hits.  Only the seam
    segments that can be nearest to some hit are projected (the hits of one
    frame lie within a few centimetres of each other; see
    :meth:`_nearest`), so the cost does not grow with the seam's length;
    the per-hit arithmetic is :meth:`Workpiece.nearest_many`'s, so the
    frames are the same bit for bit (tests/mvs/test_mvs_camera.py checks
    against that straightforward form).
    """

    def __init__(self, workpiece: Workpiece, calib: MvsCalibration = MvsCalibration(),
                 noise: CameraNoise = CameraNoise(), standoff_mm: float = 150.0):
        self.workpiece = workpiece
        self.calib = calib
        self.noise = noise
        self.standoff_mm = float(standoff_mm)
        self._y_rows = calib.lateral_of(np.arange(ROWS, dtype=float))
        # the rays' start points in S [mm]: standoff_mm before the measuring point, one per row
        self._origins_s = np.stack([np.full(ROWS, -self.standoff_mm), self._y_rows, np.zeros(ROWS)], axis=1)
        # a 3-D seam (issue 15: rise, curves, roll and step profiles, gaps, tacks): droid.sim.seam3d's renderer
        self._seam3d = None if workpiece.planar else workpiece.seam
        self._segments = workpiece._all  # the seam's segments and its two straight extensions
        self._distances = [_distance_fn(seg) for seg in self._segments]
        wp = workpiece
        self._along_mm = (-wp.lead_in_mm, wp.length_mm + wp.lead_out_mm)  # the surfaces' extent in s
        self._seen: tuple | None = None  # (pose key, workpiece, profile) of the last frame (see frame)

    def _nearest(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s [mm], lateral [mm]) of the nearest seam point of the (2 ROWS, 2) hits, as Workpiece.nearest_many.

        The hits of each plane lie on a line, in row order (each is affine in
        the row), so the four end hits bound them all: their centre c and
        radius R (plus a rounding margin).  The segment nearest to c gives
        an upper bound D of every hit's nearest distance (the hits' largest
        distance to it); a segment farther than D + R from c cannot be
        nearer to any hit (triangle inequality) and is skipped.  The others
        are projected in the workpiece's order with nearest_many's strict
        ``<``, so ties resolve as there.
        """
        (x0, y0), (x1, y1), (x2, y2), (x3, y3) = xy[_END_HITS].tolist()
        cx, cy = (x0 + x1 + x2 + x3) / 4, (y0 + y1 + y2 + y3) / 4
        radius = max(math.hypot(x0 - cx, y0 - cy), math.hypot(x1 - cx, y1 - cy),
                     math.hypot(x2 - cx, y2 - cy), math.hypot(x3 - cx, y3 - cy))
        radius += 1e-9 * (1.0 + abs(cx) + abs(cy) + radius)  # the hits' rounding off their line
        d_c = [dist(cx, cy) for dist in self._distances]
        best = min(range(len(d_c)), key=d_c.__getitem__)
        first = self._segments[best].project(xy)
        farthest = float(first[0].max())
        limit = farthest + radius + 1e-9
        if farthest < math.inf and all(not d <= limit for k, d in enumerate(d_c) if k != best):
            return first[1], first[2]  # the only candidate, every distance finite (< inf): nearest_many's result
        best_d = best_s = best_lat = None
        for k, seg in enumerate(self._segments):
            if k != best and not d_c[k] <= limit:
                continue
            d, s, lat = first if k == best else seg.project(xy)
            better = d < (np.inf if best_d is None else best_d)
            best_d = np.where(better, d, np.inf if best_d is None else best_d)
            best_s = np.where(better, s, 0.0 if best_s is None else best_s)
            best_lat = np.where(better, lat, 0.0 if best_lat is None else best_lat)
        return best_s, best_lat

    def profile_mm(self, T_W_S: np.ndarray) -> np.ndarray:
        """Noise-free stripe depth x_S [mm] for each of the 240 rows (NaN = no stripe)."""
        wp = self.workpiece
        t = np.asarray(T_W_S)
        if self._seam3d is not None:
            return self._seam3d.stripe_depth_mm(t, self._y_rows, self.standoff_mm)
        origins = apply(t, self._origins_s)
        d = t[0:3, 0]
        if not float(d[2]) <= -1e-9:  # the laser does not point down onto the surfaces
            return np.full(ROWS, np.nan)
        t_up = (wp.step_mm - origins[:, 2]) / d[2]
        t_low = -origins[:, 2] / d[2]
        p_up = origins[:, 0:2] + t_up[:, None] * d[0:2]
        p_low = origins[:, 0:2] + t_low[:, None] * d[0:2]
        s, lat = self._nearest(np.concatenate([p_up, p_low]))
        # Workpiece.heights_from's tests, for both planes' hits at once: the
        # upper plane's hit is on the upper surface, the lower plane's on the lower.
        side = wp.upper_sign * lat
        along = (s >= self._along_mm[0]) & (s <= self._along_mm[1])
        side_up, side_low = side[:ROWS], side[ROWS:]
        upper = along[:ROWS] & (side_up >= 0) & (side_up <= wp.width_mm) & (t_up > 0)
        lower = along[ROWS:] & (side_low < 0) & (side_low >= -wp.width_mm) & (t_low > 0)
        # The edge face: the ray passes from beside the upper plate (at its top
        # height) to under it (at the bottom) -- it meets the face in between.
        face = ~upper & (side_up < 0) & (side_low >= 0) & (side_low <= wp.width_mm) & along[ROWS:] & (t_up > 0)
        hit = np.where(upper, t_up, np.where(lower, t_low, np.nan))  # upper, face and lower exclude each other
        if face.any():
            with np.errstate(invalid="ignore", divide="ignore"):
                t_face = t_up + (-side_up) / (side_low - side_up) * (t_low - t_up)
            hit = np.where(face, t_face, hit)
        return hit - self.standoff_mm

    def frame(self, T_W_S: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
        """One DSP frame: int16 (240,) stripe columns (-1 = none), or None if dropped.

        The noise-free profile is a function of the pose alone: a pose unchanged to the bit (the
        arms at rest) renders what it rendered last frame; the noise is drawn every frame."""
        t = np.asarray(T_W_S)
        key = (t.dtype.str, t.shape, t.tobytes(), self.standoff_mm)
        seen = self._seen
        if seen is None or seen[0] != key or seen[1] is not self.workpiece:
            seen = self._seen = (key, self.workpiece, self.profile_mm(T_W_S))
        return quantise(seen[2], self.calib, self.noise, rng)


#: Indices of the end hits of the two planes in the (2 ROWS, 2) hits array.
_END_HITS = [0, ROWS - 1, ROWS, 2 * ROWS - 1]


def _distance_fn(seg):
    """A function (x, y) -> distance [mm] from the point to the segment (line or arc), scalar math."""
    h = seg.heading0_rad
    ux, uy = math.cos(h), math.sin(h)
    sx, sy = (float(v) for v in seg.start_xy)
    length = seg.length_mm
    hypot = math.hypot
    if not seg.is_arc:
        def line(x: float, y: float) -> float:
            t = min(max((x - sx) * ux + (y - sy) * uy, 0.0), length)
            return hypot(x - sx - t * ux, y - sy - t * uy)
        return line
    sign = 1.0 if seg.sweep_rad > 0 else -1.0
    r = seg.radius_mm
    cx, cy = sx - sign * r * uy, sy + sign * r * ux
    start_radial = h - sign * math.pi / 2
    sweep = abs(seg.sweep_rad)
    ex, ey = (float(v) for v in seg.end()[0])
    atan2, two_pi = math.atan2, 2 * math.pi

    def arc(x: float, y: float) -> float:
        if (sign * (atan2(y - cy, x - cx) - start_radial)) % two_pi <= sweep:
            return abs(hypot(x - cx, y - cy) - r)
        return min(hypot(x - sx, y - sy), hypot(x - ex, y - ey))
    return arc
