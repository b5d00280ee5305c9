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

from droid.sim.mvs_frames import apply
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
    stripe = np.isfinite(col) & (col >= 0) & (col < COLUMNS)
    out = np.where(stripe, np.nan_to_num(col), NO_STRIPE).astype(np.int16)
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
    """The laser/camera/DSP twin over one workpiece (see the module docstring)."""

    def __init__(self, workpiece: Workpiece, calib: MvsCalibration = MvsCalibration(),
                 noise: CameraNoise = CameraNoise(), standoff_mm: float = 150.0):
        self.workpiece = workpiece
        self.calib = calib
        self.noise = noise
        self.standoff_mm = float(standoff_mm)
        self._y_rows = calib.lateral_of(np.arange(ROWS, dtype=float))

    def profile_mm(self, T_W_S: np.ndarray) -> np.ndarray:
        """Noise-free stripe depth x_S [mm] for each of the 240 rows (NaN = no stripe)."""
        wp = self.workpiece
        origins_s = np.stack([np.full(ROWS, -self.standoff_mm), self._y_rows, np.zeros(ROWS)], axis=1)
        origins = apply(T_W_S, origins_s)
        d = np.asarray(T_W_S)[0:3, 0]
        out = np.full(ROWS, np.nan)
        if d[2] > -1e-9:  # the laser does not point down onto the surfaces
            return out
        t_up = (wp.step_mm - origins[:, 2]) / d[2]
        t_low = -origins[:, 2] / d[2]
        p_up = origins[:, 0:2] + t_up[:, None] * d[0:2]
        p_low = origins[:, 0:2] + t_low[:, None] * d[0:2]
        s_up, lat_up = wp.nearest_many(p_up)
        s_low, lat_low = wp.nearest_many(p_low)
        upper = (wp.heights_from(s_up, lat_up) == wp.step_mm) & (t_up > 0)
        lower = (wp.heights_from(s_low, lat_low) == 0.0) & (t_low > 0)
        # The edge face: the ray passes from beside the upper plate (at its top
        # height) to under it (at the bottom) -- it meets the face in between.
        side_up, side_low = wp.upper_sign * lat_up, wp.upper_sign * lat_low
        along = (s_low >= -wp.lead_in_mm) & (s_low <= wp.length_mm + wp.lead_out_mm)
        face = ~upper & (side_up < 0) & (side_low >= 0) & (side_low <= wp.width_mm) & along & (t_up > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            t_face = t_up + (-side_up) / (side_low - side_up) * (t_low - t_up)
        t = np.where(upper, t_up, np.where(face, t_face, np.where(lower, t_low, np.nan)))
        out[:] = t - self.standoff_mm
        return out

    def frame(self, T_W_S: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
        """One DSP frame: int16 (240,) stripe columns (-1 = none), or None if dropped."""
        return quantise(self.profile_mm(T_W_S), self.calib, self.noise, rng)
