"""A faster camera twin: the same frames as :class:`droid.sim.mvs_camera.MvsCamera`, fewer segments.

``MvsCamera.profile_mm`` projects the 240 ray hits on each plane onto every
segment of the workpiece (and the two straight extensions) to find the
nearest seam point.  The hits of one frame lie within a few centimetres of
each other, so only the segments near them can be nearest.  :class:`LocalCamera`
projects both planes' hits at once and only onto the candidate segments:

1. the segment nearest to the hits' centroid gives an upper bound D of every
   hit's nearest distance (its distance to that segment);
2. a segment whose distance to the centroid exceeds D + the hits' radius
   around the centroid cannot be nearer to any hit (triangle inequality) and
   is skipped;
3. the candidates are projected in the workpiece's order with the same
   strict ``<`` as ``Workpiece.nearest_many``, so ties resolve as there.

The per-ray arithmetic is the original's, so the frames are identical (a
test compares them bit for bit); only the work is less (docs/bench-seamtrack.md).
"""
from __future__ import annotations

import math

import numpy as np

from droid.sim.mvs_camera import CameraNoise, MvsCamera, quantise
from droid.sim.mvs_frames import apply
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.wire import ROWS


def _distance(seg, x: float, y: float) -> float:
    """Distance [mm] from the point (x, y) to a workpiece segment (line or arc), scalar math."""
    h = seg.heading0_rad
    ux, uy = math.cos(h), math.sin(h)
    sx, sy = seg.start_xy
    if not seg.is_arc:
        t = min(max((x - sx) * ux + (y - sy) * uy, 0.0), seg.length_mm)
        return math.hypot(x - sx - t * ux, y - sy - t * uy)
    sign = 1.0 if seg.sweep_rad > 0 else -1.0
    cx, cy = sx - sign * seg.radius_mm * uy, sy + sign * seg.radius_mm * ux
    start_radial = h - sign * math.pi / 2
    delta = (sign * (math.atan2(y - cy, x - cx) - start_radial)) % (2 * math.pi)
    if delta <= abs(seg.sweep_rad):
        return abs(math.hypot(x - cx, y - cy) - seg.radius_mm)
    end = seg.end()[0]
    return min(math.hypot(x - sx, y - sy), math.hypot(x - float(end[0]), y - float(end[1])))


class LocalCamera(MvsCamera):
    """:class:`MvsCamera` whose nearest-seam search looks only at the segments near the frame."""

    def __init__(self, workpiece, calib: MvsCalibration = MvsCalibration(),
                 noise: CameraNoise = CameraNoise(), standoff_mm: float = 150.0):
        super().__init__(workpiece, calib, noise, standoff_mm)
        self._segments = workpiece._all  # the seam's segments and its two straight extensions

    def _nearest(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, lateral) of the nearest seam point for (N, 2) points, as Workpiece.nearest_many."""
        c = xy.mean(axis=0)
        radius = float(np.max(np.hypot(xy[:, 0] - c[0], xy[:, 1] - c[1])))
        cx, cy = float(c[0]), float(c[1])
        d_c = [_distance(seg, cx, cy) for seg in self._segments]
        best = min(range(len(d_c)), key=d_c.__getitem__)
        first = self._segments[best].project(xy)
        bound = float(np.max(first[0]))
        best_d = np.full(len(xy), np.inf)
        best_s = np.zeros(len(xy))
        best_lat = np.zeros(len(xy))
        for k, (seg, dc) in enumerate(zip(self._segments, d_c)):
            if k != best and dc > bound + radius + 1e-9:
                continue
            d, s, lat = first if k == best else seg.project(xy)
            better = d < best_d
            best_d = np.where(better, d, best_d)
            best_s = np.where(better, s, best_s)
            best_lat = np.where(better, lat, best_lat)
        return best_s, best_lat

    def profile_mm(self, T_W_S: np.ndarray) -> np.ndarray:
        """Noise-free stripe depth x_S [mm] per row (NaN = no stripe); as MvsCamera.profile_mm."""
        wp = self.workpiece
        origins_s = np.stack([np.full(ROWS, -self.standoff_mm), self._y_rows, np.zeros(ROWS)], axis=1)
        origins = apply(T_W_S, origins_s)
        d = np.asarray(T_W_S)[0:3, 0]
        out = np.full(ROWS, np.nan)
        if d[2] > -1e-9:
            return out
        t_up = (wp.step_mm - origins[:, 2]) / d[2]
        t_low = -origins[:, 2] / d[2]
        p_up = origins[:, 0:2] + t_up[:, None] * d[0:2]
        p_low = origins[:, 0:2] + t_low[:, None] * d[0:2]
        s_both, lat_both = self._nearest(np.concatenate([p_up, p_low]))
        s_up, s_low = s_both[:ROWS], s_both[ROWS:]
        lat_up, lat_low = lat_both[:ROWS], lat_both[ROWS:]
        upper = (wp.heights_from(s_up, lat_up) == wp.step_mm) & (t_up > 0)
        lower = (wp.heights_from(s_low, lat_low) == 0.0) & (t_low > 0)
        side_up, side_low = wp.upper_sign * lat_up, wp.upper_sign * lat_low
        along = (s_low >= -wp.lead_in_mm) & (s_low <= wp.length_mm + wp.lead_out_mm)
        face = ~upper & (side_up < 0) & (side_low >= 0) & (side_low <= wp.width_mm) & along & (t_up > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            t_face = t_up + (-side_up) / (side_low - side_up) * (t_low - t_up)
        t = np.where(upper, t_up, np.where(face, t_face, np.where(lower, t_low, np.nan)))
        out[:] = t - self.standoff_mm
        return out

    def frame(self, T_W_S: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
        return quantise(self.profile_mm(T_W_S), self.calib, self.noise, rng)
