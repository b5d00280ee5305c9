"""The line-laser sensor's serial line to the Brain: grammar, parser, splitter, client core.

Thesis §5.4: sensor.exe sends each frame's result "to the serial port as ASCII
data which are delimited by commas" at 60 Hz; §6.1: the tool-tip measuring
sensor reports the same three values.  The grammar (one line a frame, ``\\n``
terminated, an optional ``\\r`` before it is ignored)::

    line    = reading | "invalid"
    reading = mm "," mm "," rad ["," stamp]
    mm      = ["-"] 1*4DIGIT "." 3DIGIT        ; x then y, sensor frame S [mm]
    rad     = ["-"] DIGIT "." 5DIGIT           ; roll about S's z [rad], |roll| <= pi
    stamp   = 1*5DIGIT                         ; capture time of the frame [ms], modulo 100000

The stamp (issue 12, an addition; the thesis's plain ``x,y,roll`` lines still
parse) is the instant the camera took the frame, in milliseconds of the
cell's CLOCK_MONOTONIC modulo :data:`STAMP_MODULO_MS`.  The Brain side
(:class:`SensorClientCore`) turns it into the reading's age at reception; a
stamp from the future, older than :data:`STAMP_MAX_AGE_MS`, or older than the
previous stamped line (out of order) drops the reading (invalid) and is
counted (``stamp_dropped``).

Anything else is *garbled*: it counts as an invalid reading and is counted.
An invalid reading (a frame without a feature, a garbled line, a stale link)
carries x = y = roll = 0, as the thesis's seamtrack expects (§6.2.5).

This module lives in the Brain package because both ends speak it: the
Brain's serial link (:mod:`droid.brain.runtime.sensor_link`) parses it, and the sensor
program (:mod:`droid.subunits.mvs.sensor`, through
:mod:`droid.subunits.mvs.protocol`) and the tool-tip twin format it.  It is
pure: nothing here blocks, reads a clock or does I/O.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from droid.brain.plumbing.serial_line import BITS_PER_BYTE  # noqa: F401  (re-exported: droid.subunits.mvs.wire)
from droid.brain.plumbing.serial_line import LineSplitter as _SerialLineSplitter

# -- grammar constants (droid.subunits.mvs.wire re-exports them) ------------------
#: A valid line: "x,y,roll\n" with x, y in mm (3 decimals) and roll in rad (5 decimals).
X_DECIMALS = 3
ROLL_DECIMALS = 5
#: The line sent for a frame without a feature.
INVALID_LINE = b"invalid"
LINE_END = b"\n"
#: Longest line the grammar allows ("-9999.999,-9999.999,-3.14159,99999" + "\r").
MAX_LINE_BYTES = 38
#: The stamp field counts milliseconds modulo this (wraps every 100 s).
STAMP_MODULO_MS = 100_000
#: A stamp older than this at reception [ms] is refused (a frame that old is no reading).
STAMP_MAX_AGE_MS = 1_000
#: Line rate of the sensors [lines/s] (one a video frame, thesis §5.4, §6.1).
LINE_RATE_HZ = 60.0
#: Bits on the wire per byte (8N1): droid.brain.plumbing.serial_line's, imported above.
#: Lowest baud rate accepted.  A line for a feature inside the default field of
#: view is at most 25 bytes ("-25.600,-24.000,-1.57080\n"), 31 with a stamp: 60 lines/s
#: x 31 bytes x 10 bits = 18 600 bit/s, which 9600 baud cannot carry and 19200 can.
MIN_BAUD = 19200
DEFAULT_BAUD = 19200

_READING = re.compile(rb"(-?[0-9]{1,4}\.[0-9]{3}),(-?[0-9]{1,4}\.[0-9]{3}),(-?[0-9]\.[0-9]{5})(?:,([0-9]{1,5}))?")
_MM_LIMIT = 10_000.0  # |x|, |y| must format to at most 4 integer digits
_ROLL_LIMIT = round(math.pi, ROLL_DECIMALS)


def seam_transform(x_mm: float, y_mm: float, roll_rad: float) -> np.ndarray:
    """T_S_seam: the seam frame in the sensor frame from one reading (4x4, mm).

    Origin at the feature point (x, y, 0); rotated by ``roll`` about S's z, so
    the seam frame's y axis runs along the surface and its x axis along the
    surface normal (away from the sensor).  This is the Status ``x, y, z, R``
    of thesis Table 3.3: x, y, z = 0, R = Rz(roll).
    """
    c, s = math.cos(roll_rad), math.sin(roll_rad)
    t = np.eye(4)
    t[0:2, 0:2] = [[c, -s], [s, c]]
    t[0:2, 3] = (x_mm, y_mm)
    return t


@dataclass(frozen=True)
class LineReading:
    """One line from the sensor, as the wire carries it; invalid readings carry zeros.

    Not :class:`droid.tasks.seam.delay.Reading`, the seam tracker's input: that
    one carries the capture instant in heartbeat ticks and the delay buffer's
    ``zeroed`` mark; this one the line's own ``stamp_ms`` (mod
    ``STAMP_MODULO_MS``) and its age at reception.  The Brain's Status sits
    between them (droid.brain.runtime.sensor_link fills it, the tracker reads it).
    """

    valid: bool
    x_mm: float = 0.0
    y_mm: float = 0.0
    roll_rad: float = 0.0
    stamp_ms: int | None = None  # the frame's capture time [ms mod STAMP_MODULO_MS]; None: not stamped
    age_ms: int | None = None  # set by SensorClientCore: the capture's age at reception [ms]

    def transform(self) -> np.ndarray:
        """T_S_seam for this reading (see :func:`seam_transform`)."""
        return seam_transform(self.x_mm, self.y_mm, self.roll_rad)


INVALID = LineReading(valid=False)


@dataclass(frozen=True)
class Garbled:
    """A line that does not match the grammar; it counts as invalid."""

    line: bytes
    reason: str
    valid: bool = False


def stamp_ms_of(t_ns: int) -> int:
    """The stamp field of a capture at CLOCK_MONOTONIC ``t_ns`` [ns]."""
    return int(t_ns // 1_000_000) % STAMP_MODULO_MS


def format_line(feature, stamp_ms: int | None = None) -> bytes:
    """The line for a feature (anything with x_mm, y_mm, roll_rad), or ``invalid`` for None.

    ``stamp_ms``: the frame's capture time (:func:`stamp_ms_of`), appended as the
    optional fourth field; None: the thesis's plain line.

    A feature the grammar cannot carry (non-finite, |x| or |y| >= 10 m,
    |roll| > pi) is sent as ``invalid``: the sensor never sends a line its
    reader would reject.
    """
    if feature is None:
        return INVALID_LINE + LINE_END
    x, y, roll = float(feature.x_mm), float(feature.y_mm), float(feature.roll_rad)
    if not all(math.isfinite(v) for v in (x, y, roll)) or max(abs(x), abs(y)) >= _MM_LIMIT - 0.0005 \
            or abs(round(roll, ROLL_DECIMALS)) > _ROLL_LIMIT:
        return INVALID_LINE + LINE_END
    # + 0.0 turns a -0.0 after rounding into 0.0: no "-0.000" on the line
    x, y, roll = round(x, X_DECIMALS) + 0.0, round(y, X_DECIMALS) + 0.0, round(roll, ROLL_DECIMALS) + 0.0
    stamp = "" if stamp_ms is None else f",{int(stamp_ms) % STAMP_MODULO_MS}"
    return f"{x:.{X_DECIMALS}f},{y:.{X_DECIMALS}f},{roll:.{ROLL_DECIMALS}f}{stamp}".encode() + LINE_END


def parse_line(line: bytes) -> LineReading | Garbled:
    """Parse one line (its ``\\n`` and ``\\r`` optional) into a LineReading or Garbled."""
    body = bytes(line)
    if body.endswith(LINE_END):
        body = body[:-1]
    if body.endswith(b"\r"):
        body = body[:-1]
    if body == INVALID_LINE:
        return INVALID
    m = _READING.fullmatch(body)
    if m is None:
        return Garbled(body, "does not match x,y,roll")
    x, y, roll = (float(g) for g in m.groups()[:3])
    if abs(roll) > _ROLL_LIMIT:
        return Garbled(body, "roll beyond pi")
    stamp = m.group(4)
    return LineReading(valid=True, x_mm=x, y_mm=y, roll_rad=roll, stamp_ms=None if stamp is None else int(stamp))


class LineSplitter(_SerialLineSplitter):
    """Accumulates serial chunks and yields complete lines (without ``\\n``).

    The buffer is bounded: of a line longer than ``max_line_bytes`` only the
    first ``max_line_bytes + 1`` bytes are kept (and yielded, in order, where
    the parser rejects them as garbled); ``overlong`` counts such lines.
    :meth:`resync` (a port just reopened) skips to the next line end and
    counts the bytes in ``skipped``.  The cell's one line splitter
    (:class:`droid.brain.plumbing.serial_line.LineSplitter`) with this grammar's policy.
    """

    def __init__(self, max_line_bytes: int = MAX_LINE_BYTES):
        super().__init__(max_line_bytes, LINE_END)


class SensorClientCore:
    """The Brain side of the serial link, as a core: bytes in, newest reading out.

    Call :meth:`feed` once a tick with whatever arrived (possibly nothing).
    Garbled lines (overlong ones included) count as invalid readings and are
    counted.  When no complete line has arrived for more than
    ``stale_after_feeds`` consecutive calls the link is stale and the reading
    is invalid.
    """

    def __init__(self, stale_after_feeds: int = 6, max_line_bytes: int = MAX_LINE_BYTES):
        self.stale_after_feeds = stale_after_feeds
        self.splitter = LineSplitter(max_line_bytes)
        self.lines = 0  # complete lines, garbled ones included
        self.valid = 0
        self.invalid = 0  # "invalid" lines and garbled lines
        self.garbled = 0
        self.feeds_since_line = 0
        self.latest: LineReading = INVALID
        self.stamp_dropped = 0  # stamped readings dropped: from the future, too old or out of order
        self._last_capture_ms: int | None = None  # unwrapped capture time of the last stamped line [ms]

    @property
    def stale(self) -> bool:
        """True when no line has arrived for more than ``stale_after_feeds`` feeds."""
        return self.feeds_since_line > self.stale_after_feeds

    def _check_stamp(self, r: LineReading, now_ns: int | None) -> LineReading:
        """A stamped reading with its age at ``now_ns``, or INVALID (dropped, counted)."""
        if now_ns is None:
            return r
        now_ms = int(now_ns // 1_000_000)
        age = (now_ms - r.stamp_ms) % STAMP_MODULO_MS
        capture = now_ms - age
        if age > STAMP_MAX_AGE_MS or (self._last_capture_ms is not None and capture < self._last_capture_ms):
            self.stamp_dropped += 1  # from the future (wraps to a huge age), too old, or out of order
            return INVALID
        self._last_capture_ms = capture
        return LineReading(True, r.x_mm, r.y_mm, r.roll_rad, r.stamp_ms, age)

    def feed(self, data: bytes, now_ns: int | None = None) -> LineReading:
        """Take the bytes read this tick; return the newest reading (INVALID when stale).

        ``now_ns``: CLOCK_MONOTONIC at reception [ns], for stamped lines (None: stamps
        are kept as they are, unchecked)."""
        lines = self.splitter.feed(data)
        for line in lines:
            result = parse_line(line)
            self.lines += 1
            if isinstance(result, Garbled):
                self.garbled += 1
                result = INVALID
            elif result.valid and result.stamp_ms is not None:
                result = self._check_stamp(result, now_ns)
            if result.valid:
                self.valid += 1
            else:
                self.invalid += 1
            self.latest = result
        self.feeds_since_line = 0 if lines else self.feeds_since_line + 1
        return INVALID if self.stale else self.latest

    def resync(self) -> None:
        """After the port was (re)opened: ignore everything up to the next line end."""
        self.splitter.resync()
