"""droid-mvs's cycle as one station: a frame in, the "x,y,roll[,ms]" line out (issue 25 item 3;
thesis §5.4, sensor.exe).

The real-time shell (``droid-mvs``, :mod:`droid.subunits.mvs.sensor`), the lockstep chain
(:func:`droid.sim.mvs.lockstep.mvs_lockstep`) and the experiments' lead sensor
(:class:`droid.sim.mvs.trial_sensors.LeadSensor`) all step :class:`MvsStation`, so the rules
between the DSP board and the serial line exist once:

* **a frame**: the core (:class:`SensorCore`) extracts the lap-joint feature and formats
  the line, with the frame's capture stamp [ms] as its fourth field when the shell gives
  one (``droid-mvs --stamp``);
* **the timeout rule**, counted in frame periods (never in seconds): when no frame has
  come for ``timeout_frames`` frame periods since the last line (or since the start), the
  line is ``invalid`` and the count starts again; from then until the next frame the
  station is *stale*.  The shell says how many frame periods went by without a frame
  (:meth:`MvsStation.on_wait`): lockstep one a frame slot that brought none, droid-mvs a
  whole timeout for each retrace wait that timed out;
* **the reopen rule**: a port found closed is tried once a line (the line is lost, and
  counted, when it does not open); a write that fails and closes the port loses its line
  -- with ``reopen`` (droid-mvs in a cell) the next line tries the port again, without it
  the run ends (:attr:`MvsOutput.fatal`); a write that could not complete in time with the
  port kept open is an overrun, counted by the port (``PortLink.write_timeouts``).

No clock, no board, no signals, no files: the shell waits for the retrace (with its
timeout in seconds), opens the port, writes the recording and reports.  ``port`` is
anything with ``is_open``, ``open()``, ``write(bytes) -> bool`` and ``last_error`` -- the
cell's :class:`~droid.brain.plumbing.serial_port.PortLink`, lockstep's in-memory cable -- or None:
the caller takes :attr:`MvsOutput.line` itself.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.feature import Feature, FeatureParams, extract
from droid.subunits.mvs.protocol import format_line

#: The retrace timeout [frame periods]: 'invalid' after this many without a frame (0.1 s at 60 Hz).
RETRACE_TIMEOUT_FRAMES = 6
#: Float noise of a timeout converted from seconds (S x frame rate) must not lose a frame [frame periods].
_FRAME_EPS = 1e-6


@dataclass
class SensorCore:
    """sensor.exe's per-frame work as a core: 240 columns in, one serial line out."""

    calib: MvsCalibration
    params: FeatureParams = FeatureParams()
    frames: int = 0
    valid: int = 0
    last: Feature | None = None

    def process(self, rows: np.ndarray) -> Feature | None:
        """Extract the feature of one frame (None = invalid) and count it."""
        self.last = extract(rows, self.calib, self.params)
        self.frames += 1
        self.valid += self.last is not None
        return self.last

    def step(self, rows: np.ndarray, stamp_ms: int | None = None) -> bytes:
        """One frame -> the line to send ("x,y,roll\\n" or "invalid\\n"); with ``stamp_ms`` the
        frame's capture stamp as the line's optional fourth field (droid.brain.plumbing.sensor_line)."""
        return format_line(self.process(rows), stamp_ms)

    @property
    def invalid(self) -> int:
        return self.frames - self.valid


@dataclass(frozen=True)
class MvsOutput:
    """What one call of the station did."""

    line: bytes | None = None  # the line due now (None: none -- a frame slot inside the timeout)
    sent: bool = False  # the port took it
    port_error: str | None = None  # the port failed on this line and is closed (the line is lost)
    fatal: bool = False  # ... and the station does not reopen: the run ends


class MvsStation:
    """droid-mvs's per-frame cycle between the DSP board and the serial line (module docstring).

    ``timeout_frames`` [frame periods] > 0; droid-mvs gives ``--retrace-timeout`` x the frame
    rate (6 by default).  State, for the shells and the tests: ``waited_frames`` (frame
    periods since the last line), ``stale`` (the last line was a timeout's), ``timeouts``
    (timeout lines), ``missed`` (frames the board wrote that the shell was too slow for),
    ``reopen_attempts`` / ``reopened`` (tries to open a closed port / the ones that worked)
    and ``lost`` (lines lost with the port)."""

    def __init__(self, core: SensorCore, port=None, *, timeout_frames: float = RETRACE_TIMEOUT_FRAMES,
                 reopen: bool = False) -> None:
        if not timeout_frames > 0:
            raise ValueError(f"timeout_frames must be > 0, got {timeout_frames!r}")
        self.core = core
        self.port = port
        self.timeout_frames = float(timeout_frames)
        self.reopen = reopen
        self.waited_frames = 0.0
        self.stale = False
        self.timeouts = 0
        self.missed = 0
        self.reopen_attempts = 0
        self.reopened = 0
        self.lost = 0

    def on_frame(self, rows: np.ndarray, stamp_ms: int | None = None, missed: int = 0) -> MvsOutput:
        """A frame came: its line, sent.  ``stamp_ms``: its capture stamp (the line's fourth
        field); ``missed``: frames the board wrote before it that nobody read."""
        self.missed += missed
        self.waited_frames = 0.0
        self.stale = False
        return self._send(self.core.step(rows, stamp_ms))

    def on_wait(self, frames: float = 1.0) -> MvsOutput:
        """``frames`` more frame periods went by without a frame: 'invalid', sent, once they
        add up to the timeout since the last line; else nothing (``line`` None)."""
        self.waited_frames += frames
        if self.waited_frames + _FRAME_EPS < self.timeout_frames:
            return MvsOutput()
        self.waited_frames = 0.0
        self.timeouts += 1
        self.stale = True
        return self._send(format_line(None))

    def _send(self, line: bytes) -> MvsOutput:
        port = self.port
        if port is None:
            return MvsOutput(line)
        if not port.is_open:  # failed on an earlier line: one try a line
            self.reopen_attempts += 1
            if not port.open():
                self.lost += 1
                return MvsOutput(line)
            self.reopened += 1
        if port.write(line):
            return MvsOutput(line, sent=True)
        if port.is_open:  # the write timed out, the port kept: an overrun (the port counts it)
            return MvsOutput(line)
        self.lost += 1
        return MvsOutput(line, port_error=port.last_error, fatal=not self.reopen)
