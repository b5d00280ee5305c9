"""The measuring sensor "virtually at the tool tip" (thesis §6.1).

The thesis measures tracking error with a second MVS sensor placed virtually
at the tool tip: the lateral and height deviation from the seam [mm] and the
surface roll [rad], at 60 Hz, measuring only.  Here it is the exact geometry
(:func:`measure`) seen through the lead sensor's noise model
(:class:`ToolNoise`, :func:`noisy`): the tool-tip sensor is a second MVS, so
its readings scatter as the lead sensor's do (issue 13 item 5).

The tool frame T is read like the sensor frame S (docs/mvs.md): x along the
tool axis toward the surface (depth), y lateral, z the travel direction; its
x-y plane is the virtual laser sheet.  The seam point measured is where the
seam's foot (the lower surface along the seam) crosses that plane, expressed
in T:

* ``height_mm`` = its x: how far the seam lies beyond the tool tip along the
  tool axis (+ = the tip is above the seam);
* ``lateral_mm`` = its y (+ = the seam lies toward +y of the tool);
* ``roll_rad`` = the surface's rotation about T's z, as the lead sensor
  reports it (0 when the surface is perpendicular to x);
* ``s_mm`` = the arc length of that seam point.

All three deviations are zero when the tool sits on the seam in the nominal
orientation.  Applied to the lead sensor's pose S, ``measure`` gives what an
ideal line-laser sensor would report -- the ground truth of the camera twin.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from droid.sim.mvs.frames import apply, invert, rot_z, translation
from droid.sim.seam3d import ToolReading  # noqa: F401 (the sensor's reading; defined beside Seam3D.measure)
from droid.sim.workpiece import Workpiece

#: The lead sensor's reading scatter through the camera chain at REFERENCE_JITTER_PX of stripe
#: jitter (0.5 px, 2-10 % spurious rows: the feature extraction rejects the spurious rows;
#: docs/bench-mvs.md): the ``ideal`` lead sensor model's sigmas (droid.sim.mvs.trial_sensors).
REFERENCE_JITTER_PX = 0.5
SIGMA_HEIGHT_MM = 0.012  # x (depth): the column direction, fitted over many rows
SIGMA_LATERAL_MM = 0.056  # y: the step's row, placed between rows
SIGMA_ROLL_RAD = 0.0005

#: Stop the search when the seam point is this close to the sheet [mm].
TOLERANCE_MM = 1e-9
MAX_ITERATIONS = 50


@dataclass(frozen=True)
class ToolNoise:
    """The lead sensor's noise model, as the ideal sensor model states it: Gaussian scatter of
    the reading [mm, mm, rad] and lost frames.  :meth:`like_camera` scales the camera chain's
    scatter at :data:`REFERENCE_JITTER_PX` with a :class:`~droid.sim.mvs.camera.CameraNoise`'s
    stripe jitter and takes its drop probability (its spurious rows are the feature
    extraction's to reject; their effect is inside the reference sigmas).  The default: exact."""

    sigma_height_mm: float = 0.0
    sigma_lateral_mm: float = 0.0
    sigma_roll_rad: float = 0.0
    drop_probability: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.sigma_height_mm, self.sigma_lateral_mm, self.sigma_roll_rad, self.drop_probability)
        if not all(math.isfinite(v) and v >= 0 for v in vals) or self.drop_probability > 1:
            raise ValueError(f"bad tool-sensor noise {self}")

    @classmethod
    def like_camera(cls, noise) -> "ToolNoise":
        k = float(noise.jitter_px) / REFERENCE_JITTER_PX
        return cls(SIGMA_HEIGHT_MM * k, SIGMA_LATERAL_MM * k, SIGMA_ROLL_RAD * k, float(noise.drop_probability))

    @property
    def exact(self) -> bool:
        return not (self.sigma_height_mm or self.sigma_lateral_mm or self.sigma_roll_rad or self.drop_probability)


def noisy(m: ToolReading | None, noise: ToolNoise, rng: np.random.Generator) -> ToolReading | None:
    """``m`` through the noise model: four random numbers drawn every call (None or not, exact
    or not), so a seeded run is reproducible whatever the readings are.  ``s_mm`` (the seam
    coordinate, the truth's) is not a measurement and stays."""
    z = rng.standard_normal(3)
    lost = rng.random() < noise.drop_probability
    if m is None or lost:
        return None
    return ToolReading(lateral_mm=m.lateral_mm + noise.sigma_lateral_mm * z[1],
                       height_mm=m.height_mm + noise.sigma_height_mm * z[0],
                       roll_rad=m.roll_rad + noise.sigma_roll_rad * z[2], s_mm=m.s_mm)


def seam_frame(workpiece: Workpiece, s_mm: float) -> np.ndarray:
    """T_W_seam: the nominal sensor frame on the seam foot at arc length s [mm].

    Origin on the seam at the lower surface's height, x = -z_W (into the
    surface), y = the left normal, z = the seam's heading.  A 3-D seam
    (issue 15): x = -its rolled surface normal, y its lateral, z its tangent.
    """
    return workpiece.seam_frame(s_mm)


def pose_for_reading(workpiece: Workpiece, s_mm: float, x_mm: float = 0.0, y_mm: float = 0.0,
                     roll_rad: float = 0.0) -> np.ndarray:
    """T_W_S of a sensor that would read the feature (x, y) [mm] and roll [rad] at arc length s.

    The seam frame seen from S is ``translation(x, y, 0) @ rot_z(roll)``
    (the transform a Brain builds from a reading), so
    T_W_S = T_W_seam @ inverse(that).
    """
    return seam_frame(workpiece, s_mm) @ invert(translation(x_mm, y_mm, 0.0) @ rot_z(roll_rad))


def _seam_point(workpiece: Workpiece, s_mm: float) -> np.ndarray:
    xy, _ = workpiece.point_at(s_mm)
    return np.array([xy[0], xy[1], 0.0])


def measure(T_W_tool: np.ndarray, workpiece: Workpiece) -> ToolReading | None:
    """Seam deviation seen from the frame ``T_W_tool`` (4x4, mm), or None.

    None when the seam does not cross the frame's x-y plane (the frame's z is
    perpendicular to the seam's direction) or the search does not converge.
    """
    T_W_tool = np.asarray(T_W_tool, float)
    if not workpiece.planar:  # a 3-D seam (issue 15): its sampled foot crossing the plane
        return workpiece.seam.measure(T_W_tool)
    T_tool_W = invert(T_W_tool)
    s, _, _ = workpiece.nearest(T_W_tool[0:3, 3])

    def z_in_tool(s_mm: float) -> float:
        return float(apply(T_tool_W, _seam_point(workpiece, s_mm))[2])

    for _ in range(MAX_ITERATIONS):
        f = z_in_tool(s)
        if abs(f) < TOLERANCE_MM:
            break
        h = 1e-3
        slope = (z_in_tool(s + h) - z_in_tool(s - h)) / (2 * h)
        if abs(slope) < 1e-6:
            return None
        s -= max(-100.0, min(100.0, f / slope))  # damped Newton step [mm]
    else:
        return None
    p = apply(T_tool_W, _seam_point(workpiece, s))
    normal = T_tool_W[0:3, 0:3] @ np.array([0.0, 0.0, 1.0])  # toward the sensor, in T
    # Surface line within the sheet: v = n x z = (n_y, -n_x); roll = atan2(-v_x, v_y).
    roll = math.atan2(-normal[1], -normal[0])
    return ToolReading(lateral_mm=float(p[1]), height_mm=float(p[0]), roll_rad=roll, s_mm=float(s))
