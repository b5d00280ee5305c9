"""The two sensors of a trial: the lead MVS sensor and the tool-tip measuring sensor (thesis §5.3-5.4, §6.1).

Lead sensor (``camera`` model): the camera/DSP twin renders the
240 stripe columns for the sensor's true pose (:class:`~droid.sim.mvs.camera.MvsCamera`,
the renderer of the real-time cell's camera twin), droid-mvs's station
(:class:`~droid.subunits.mvs.station.MvsStation`) extracts the feature
(droid.subunits.mvs.feature, Strauss's method) and formats the serial line,
the Brain's parser reads it back (rounded to the line's 3 and 5 decimals):
the reading the Status record holds (the trial hands it to the tracker as its
``Reading``).  A dropped frame is the station's too: no line (the Status keeps the one it has) until the retrace timeout, counted in
frame periods, sends ``invalid``.  ``ideal`` model: the exact geometry at
the sensor frame (``tool_sensor.measure``, in closed form:
:mod:`droid.sim.mvs.crossing`), invalid outside the field of view the
feature extraction can use, plus Gaussian noise of the size the camera chain
shows (docs/bench-mvs.md), through the same serial-line rounding.

Tool-tip sensor (:class:`ToolTipSensor`): the geometry at the tool frame
(``tool_sensor.measure``, closed form), "virtually at the tool tip" (§6.1):
lateral and height deviation and roll, through the lead sensor's noise model
(``tool_sensor.ToolNoise.like_camera`` of the trial's camera noise: the
``ideal`` model's scatter, seeded apart from the lead sensor).  It reports
along the seam's straight extensions too (before the seam start the tool is
still on the extension at the start of a trial).  :func:`tool_reading` is the
exact geometry -- the trial's truth (seam progress, the stop position).

Timing (as in the real-time cell, docs/mvs.md): a frame taken at tick k
reaches the Brain's Status within the next tick; the 30 Hz seam-tracking
cycle at an even tick k reads the frame of tick k - 1.  Frames nobody reads
(those of even ticks) are not rendered: they would only be overwritten.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from droid.brain.plumbing.sensor_line import Garbled, LineReading, format_line, parse_line
from droid.sim.mvs.crossing import SeamCrossing
from droid.sim.mvs.camera import CameraNoise, MvsCamera
from droid.sim.mvs.tool_sensor import (SIGMA_HEIGHT_MM, SIGMA_LATERAL_MM, SIGMA_ROLL_RAD, ToolNoise, ToolReading,
                                       noisy)
from droid.sim.workpiece import Workpiece
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.feature import FeatureParams
from droid.subunits.mvs.station import MvsStation, SensorCore
from droid.subunits.mvs.wire import ROWS

SENSOR_MODELS = ("camera", "ideal")

#: Camera noise of the trials (as the default cell, droid/cells/sim.toml).
DEFAULT_NOISE = CameraNoise(jitter_px=0.5, spurious_fraction=0.02, drop_probability=0.0)

#: ``ideal`` model: noise sigmas of the camera chain at 0.5 px jitter (docs/bench-mvs.md).
IDEAL_SIGMA_Y_MM = SIGMA_LATERAL_MM
IDEAL_SIGMA_X_MM = SIGMA_HEIGHT_MM
IDEAL_SIGMA_ROLL_RAD = SIGMA_ROLL_RAD


@dataclass(frozen=True)
class _Values:
    x_mm: float
    y_mm: float
    roll_rad: float


class LeadSensor:
    """The MVS lead sensor of one trial: its pose in W -> the Brain's reading.

    The MVS package's ``lead`` lockstep model (droid.subunits.mvs.device; DevicePackage.lockstep_models):
    a trial whose layout's ``sensor`` is an MVS subunit makes its lead sensor of this class
    (droid.sim.trial_cell.TrialCell.lead_sensor) and its tool-tip sensor with :meth:`tool_tip`.
    ``noise``: the camera's (None: :data:`DEFAULT_NOISE`, the trials').
    ``frames_per_read``: frame periods between two :meth:`read` calls -- the trial renders
    only the frames its cycles read (one a 30 Hz cycle: 2); to the station's timeout rule a
    dropped frame is that many frame periods without a frame."""

    #: the sensor models it has (a trial's ``sensor``)
    models = SENSOR_MODELS

    def __init__(self, workpiece: Workpiece, model: str = "camera", noise: CameraNoise | None = None,
                 calib: MvsCalibration = MvsCalibration(), seed: int = 0, frames_per_read: int = 1) -> None:
        if model not in SENSOR_MODELS:
            raise ValueError(f"unknown sensor model {model!r} (known: {', '.join(SENSOR_MODELS)})")
        noise = DEFAULT_NOISE if noise is None else noise
        self.model = model
        self.noise = noise
        self.workpiece = workpiece
        self.crossing = SeamCrossing(workpiece)
        self.rng = np.random.default_rng(seed)
        self.frames = 0
        self.valid = 0
        if model == "camera":
            self.camera = MvsCamera(workpiece, calib, noise)
            self.station = MvsStation(SensorCore(calib))
            self.frames_per_read = frames_per_read
        else:
            fp = FeatureParams()
            margin = (fp.min_side_rows + fp.guard_rows) * calib.lateral_mm_per_row
            half = (ROWS - 1) / 2 * calib.lateral_mm_per_row
            self.y_limit_mm = half - margin
            self.x_limit_mm = (calib.column_at_origin - 1.0) * calib.depth_mm_per_column

    def read(self, T_W_S: np.ndarray) -> LineReading | Garbled | None:
        """The line of a frame taken with the sensor frame at ``T_W_S`` (4x4, mm), as the Brain's
        parser reads it (droid.brain.plumbing.sensor_line.parse_line: the values rounded to the line's
        decimals; ``valid`` False for ``invalid``); None when the frame brought no line (dropped,
        inside the retrace timeout: the Status keeps its line).  The tracker's reading of it is
        the trial's (the Brain's Status between them, as droid.brain.runtime.sensor_link fills it)."""
        self.frames += 1
        if self.model == "camera":
            rows = self.camera.frame(T_W_S, self.rng)
            out = self.station.on_wait(self.frames_per_read) if rows is None else self.station.on_frame(rows)
            if out.line is None:
                return None
            line = out.line
        else:
            line = format_line(self._ideal(T_W_S))
        reading = parse_line(line.rstrip(b"\n"))
        self.valid += bool(reading.valid)
        return reading

    def tool_tip(self, noisy: bool = True, seed: int = 0) -> "ToolTipSensor":
        """The trial's tool-tip sensor beside this one: the same seam, through this sensor's noise
        model (``noisy``) or exact."""
        return ToolTipSensor(self.crossing, self.noise if noisy else CameraNoise(), seed=seed)

    def _ideal(self, T_W_S: np.ndarray) -> _Values | None:
        noise = self.rng.standard_normal(3)
        m = self.crossing.measure(T_W_S)
        wp = self.workpiece
        if m is None or not (-wp.lead_in_mm <= m.s_mm <= wp.length_mm + wp.lead_out_mm):
            return None
        if wp.gaps and wp.in_gap(m.s_mm):  # a gap: no feature to find (issue 15)
            return None
        if abs(m.lateral_mm) > self.y_limit_mm or abs(m.height_mm) > self.x_limit_mm:
            return None
        return _Values(m.height_mm + IDEAL_SIGMA_X_MM * noise[0], m.lateral_mm + IDEAL_SIGMA_Y_MM * noise[1],
                       m.roll_rad + IDEAL_SIGMA_ROLL_RAD * noise[2])


def tool_reading(T_W_tool: np.ndarray, crossing: SeamCrossing) -> ToolReading | None:
    """The tool-tip sensor (§6.1): deviation of the seam from the tool frame, or None."""
    m = crossing.measure(T_W_tool)
    if m is None or not all(math.isfinite(v) for v in (m.lateral_mm, m.height_mm, m.roll_rad, m.s_mm)):
        return None
    return m


#: The tool-tip sensor's random stream is the trial seed's second one (the lead sensor's the first).
TOOL_STREAM = 2


class ToolTipSensor:
    """The tool-tip measuring sensor of a trial: exact geometry through the lead sensor's noise."""

    def __init__(self, crossing: SeamCrossing, noise: CameraNoise = DEFAULT_NOISE, seed: int = 0) -> None:
        self.crossing = crossing
        self.noise = ToolNoise.like_camera(noise)
        self.rng = np.random.default_rng([int(seed), TOOL_STREAM])

    def read(self, T_W_tool: np.ndarray) -> ToolReading | None:
        return noisy(tool_reading(T_W_tool, self.crossing), self.noise, self.rng)

    def truth(self, T_W_tool: np.ndarray) -> ToolReading | None:
        """The exact reading (:func:`tool_reading`): the trial's truth -- its seam progress, the stop position."""
        return tool_reading(T_W_tool, self.crossing)
