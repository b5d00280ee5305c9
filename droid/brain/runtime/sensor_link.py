"""The Brain's serial link to a line-laser sensor (thesis §2.5, §3.3 Table 3.3, §5.4, §6.1).

The MVS PC "exports the processed feature location to the Brain Computer"
over a serial port, 60 lines a second (§2.5, §5.4); the Brain keeps the
newest one in the sensor's Status record, whose ``homed`` field is the
*invalid* flag (Table 3.3).  So for a ``line_laser`` subunit with
``link = "serial"`` the Brain-side ``droid-remote NAME`` reads a serial port
instead of talking to a ZeroMQ agent::

    [subunits.mvs]
    class = "line_laser"
    link = "serial"                      # "agent" (default): the ZeroMQ agent link
    serial = "{run}/mvs.brain.tty"       # the Brain's end of the cable (any pyserial URL)
    baud = 19200                         # >= 19200 (60 lines/s of <= 25 bytes)

Each heartbeat tick :class:`SerialPortReader` reads ``read(in_waiting)`` (never
blocks) and :class:`SensorStatusCore` turns the bytes into Status fields:

* ``x, y`` [mm] of the newest reading, ``z = 0``, ``R = Rz(roll)``
  (T_S_seam, docs/mvs.md); ``homed = 1`` when the reading is invalid (then
  x = y = 0, R = I); ``valid_count``, ``invalid_count``, ``garbled_count``
  (a garbled line counts as invalid *and* as garbled);
* ``tick``, ``updated_ns``: the heartbeat tick and CLOCK_MONOTONIC [ns] at
  which the newest line arrived;
* ``capture_age_us`` (layout v2, issue 12): for a line with a capture stamp
  (droid.brain.plumbing.sensor_line), how long before ``updated_ns`` its camera frame
  was taken [us]; ``NO_CAPTURE_AGE`` for a plain line.  A stamp from the
  future, older than a second or out of order drops the reading (invalid)
  and counts as garbled;
* ``stale = 1`` and the LINK fault after ``stale_ticks`` ticks without any
  line (and until the first line); cleared when lines flow again;
* after the port is (re)opened, bytes up to the first line end are skipped
  (the port may open in the middle of a line);
* a port that cannot be opened, or vanishes (the other end hung up, the
  device went away): ``stale = 1`` and the DEVICE fault at once; it is
  reopened with exponential back-off in ticks (``stale_ticks`` .. 120); the
  program never stops for it.

The ZeroMQ agent path of :mod:`droid.brain.runtime.remote` is unchanged; arms always
use it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from droid.brain.cell.cellfile import Cell, Subunit
from droid.brain.db.layouts import FAULT_DEVICE, FAULT_HEARTBEAT, FAULT_LINK, NO_CAPTURE_AGE
from droid.brain.plumbing.sensor_line import DEFAULT_BAUD, INVALID, MIN_BAUD, LineReading, SensorClientCore
from droid.brain.plumbing.serial_port import ReopeningPort
from droid.brain.plumbing.wire import LIVENESS_TICKS
from droid.cli import BadInput, file_number
from droid.numbers import baud_range

LINK_AGENT = "agent"
LINK_SERIAL = "serial"
LINKS = (LINK_AGENT, LINK_SERIAL)
#: Keys a line_laser subunit's table may carry besides the common ones: the
#: Brain's link (here) and the sensor program's (droid-mvs: dsp, sensor_serial,
#: calibration, board_wait, stamp).
LINE_LASER_KEYS = ("link", "serial", "baud", "dsp", "sensor_serial", "calibration", "board_wait", "stamp")
#: Most bytes taken from the port in one tick (the splitter bounds lines anyway).
MAX_READ_BYTES = 4096
#: Reopen back-off cap [ticks] (2 s at 60 Hz).
MAX_BACKOFF_TICKS = 120
_U32 = 0xFFFFFFFF


@dataclass(frozen=True)
class SerialLinkOptions:
    """The Brain end of a sensor's serial link, from ``[subunits.NAME]``."""

    url: str
    baud: int


def link_kind(cell: Cell, sub: Subunit) -> str:
    """``"agent"`` or ``"serial"``: how the Brain reaches this subunit."""
    link = sub.options.get("link", LINK_AGENT)
    if link not in LINKS:
        raise BadInput(f"{cell.path}: [subunits.{sub.name}] link must be one of {', '.join(LINKS)}, got {link!r}")
    if link == LINK_SERIAL and sub.is_arm:
        raise BadInput(f"{cell.path}: [subunits.{sub.name}] link = \"serial\" is for line_laser subunits")
    return link


def serial_link_options(cell: Cell, sub: Subunit) -> SerialLinkOptions:
    """Check a serial-linked line_laser subunit's table; BadInput names the key."""
    where = f"{cell.path}: [subunits.{sub.name}]"
    extra = sorted(k for k in sub.options if k not in LINE_LASER_KEYS)
    if extra:
        raise BadInput(f"{where} unknown key(s): {', '.join(extra)}")
    url = sub.options.get("serial")
    if not isinstance(url, str) or not url:
        raise BadInput(f"{where} link = \"serial\" needs serial = \"<port or pyserial URL>\"")
    baud = file_number(sub.options.get("baud", DEFAULT_BAUD), baud_range(MIN_BAUD), where, "baud")
    return SerialLinkOptions(url, baud)


def seam_status_fields(reading: LineReading) -> dict:
    """x, y, z, R, homed of Table 3.3 for one reading (R = Rz(roll); homed = invalid flag)."""
    if not reading.valid:
        return {"x": 0.0, "y": 0.0, "z": 0.0, "R": np.eye(3), "homed": 1}
    c, s = math.cos(reading.roll_rad), math.sin(reading.roll_rad)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return {"x": reading.x_mm, "y": reading.y_mm, "z": 0.0, "R": R, "homed": 0}


class SensorStatusCore:
    """Per heartbeat tick: bytes read + port state -> the sensor's Status fields.  Pure.

    See the module docstring for the fields.  ``stale_ticks`` ticks without a
    complete line make the link stale; so does a port that is not open, and
    after a (re)open the link stays stale until the first new line.
    """

    def __init__(self, stale_ticks: int = LIVENESS_TICKS) -> None:
        if stale_ticks < 1:
            raise ValueError("stale_ticks must be >= 1")
        self.client = SensorClientCore(stale_after_feeds=stale_ticks - 1)
        self._port_ok = False
        self._fresh = False  # a line arrived since the port was (re)opened
        self.last_line_tick = 0
        self.last_line_ns = 0

    @property
    def stale(self) -> bool:
        return not (self._port_ok and self._fresh) or self.client.stale

    def on_tick(self, tick: int, data: bytes, now_ns: int, port_ok: bool = True) -> dict:
        """Feed this tick's bytes; return the Status fields to write."""
        if port_ok and not self._port_ok:
            self.client.resync()  # the port may open mid-line: start at the next line end
            self._fresh = False
        self._port_ok = port_ok
        before = self.client.lines
        reading = self.client.feed(data if port_ok else b"", now_ns)
        if self.client.lines > before:
            self._fresh = True
            self.last_line_tick, self.last_line_ns = tick, now_ns
        stale = self.stale
        if stale:
            reading = INVALID
        fields = seam_status_fields(reading)
        fields.update(
            stale=int(stale),
            fault=(FAULT_LINK if stale else 0) | (0 if port_ok else FAULT_DEVICE),
            valid_count=self.client.valid & _U32,
            invalid_count=self.client.invalid & _U32,
            garbled_count=(self.client.garbled + self.client.stamp_dropped) & _U32,
            capture_age_us=(NO_CAPTURE_AGE if not reading.valid or reading.age_ms is None
                            else min(int(reading.age_ms) * 1000, NO_CAPTURE_AGE - 1)),
            tick=self.last_line_tick,
            updated_ns=self.last_line_ns,
        )
        return fields


class SerialPortReader(ReopeningPort):
    """The Brain's serial port: opened by URL, read without blocking, reopened with back-off.

    :meth:`poll` once a tick returns ``(bytes, port_ok)``.  A port that cannot
    be opened or fails while reading (EIO, hang-up) is closed and tried again
    after ``min_backoff_ticks`` ticks, doubling up to ``max_backoff_ticks``.
    A URL pyserial rejects as malformed is a :class:`BadInput`.  (The cell's
    one reopening port, :class:`droid.brain.plumbing.serial_port.ReopeningPort`, reading
    at most MAX_READ_BYTES a tick.)
    """

    def __init__(self, url: str, baud: int, *, min_backoff_ticks: int = 3,
                 max_backoff_ticks: int = MAX_BACKOFF_TICKS, opener=None) -> None:
        super().__init__(url, baud, min_backoff_ticks=min_backoff_ticks, max_backoff_ticks=max_backoff_ticks,
                         max_read_bytes=MAX_READ_BYTES, opener=opener)


def serve_serial(cell: Cell, sub: Subunit, ready_fd: int | None, prog: str) -> int:
    """The loop of ``droid-remote NAME`` for a serial-linked sensor (see the module docstring)."""
    import zmq

    from droid.brain.plumbing.curve import CurveHost
    from droid.brain.db.databases import open_brain
    from droid.brain.runtime.heartbeat import TickSubscriber
    from droid.brain.plumbing.link import HeartbeatWatch
    from droid.brain.runtime.program import Presence, Stop, notify_ready, presence_key

    opts = serial_link_options(cell, sub)
    Stop.install()
    status = open_brain(cell, sub, "status")
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, cell.brain_host)
    ticks = TickSubscriber(ctx, cell.heartbeat, curve, cell.brain_host)
    presence = Presence(cell.name, presence_key(prog, sub.name), f"{prog} {sub.name}")
    ticks.say = presence.say
    core = SensorStatusCore(cell.stale_ticks)
    port = SerialPortReader(opts.url, opts.baud, min_backoff_ticks=cell.stale_ticks)
    try:
        status.update(stale=1, fault=FAULT_LINK | FAULT_DEVICE, homed=1)
        port.start()  # a malformed URL stops here, before the handshake (exit 2)
        presence.ready()
        notify_ready(ready_fd)
        last_tick = 0
        watch = HeartbeatWatch.for_rate(cell.heartbeat_hz, cell.stale_ticks)
        while not Stop.requested:
            ready = ticks.sock.poll(watch.poll_ms)
            if watch.became_silent(time.monotonic_ns()):
                status.update(stale=1, fault=int(status.read()["fault"]) | FAULT_LINK | FAULT_HEARTBEAT)
            if ready:
                t = ticks.recv_latest()
                if t is not None:
                    watch.on_tick(time.monotonic_ns())  # on_tick below rewrites stale and fault
                    last_tick = t.tick
                    data, ok = port.poll()
                    status.update(**core.on_tick(t.tick, data, time.monotonic_ns(), ok))
            presence.beat(last_tick, core.client.lines, ticks.monitor.missed, ticks.lateness_max_ns,
                          bad_frames=ticks.bad_frames)
    finally:
        port.close()
        ticks.close()
        curve.close()
        ctx.term()
        status.close()
        presence.close()
    return 0
