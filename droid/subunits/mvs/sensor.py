"""droid-mvs: the MVS sensor program (thesis §5.4, sensor.exe).

Live::

    droid-mvs --dsp shm://droid.sim.mvs.dsp --serial /dev/ttyS0 [--baud 19200] [--count N]

waits for each vertical retrace of the DSP board (timeout ``--retrace-timeout``),
copies the 240 stripe columns, extracts the lap-joint feature and writes one
line "x,y,roll\\n" (or "invalid\\n") to the serial URL at the frame rate, 60 Hz.
A retrace that does not come in time also sends "invalid".  On SIGINT,
SIGTERM or after ``--count`` frames it stops and reports the frames
processed per second on stderr, as sensor.exe did on exit.  The cycle
between the frame and the port -- the feature, the line, the timeout rule
(counted in frame periods) and the port's reopening -- is
:class:`~droid.subunits.mvs.station.MvsStation`, the one lockstep steps too;
this shell waits for the retrace, keeps the clock, the recording and the signals.

Offline::

    droid-mvs --replay FILE|- [--pixels]

runs the same processing on recorded frames (one frame a line: 240 integers
separated by whitespace, negative = no stripe; blank lines and lines starting
with '#' are skipped) and prints one result a line: "x,y,roll" (mm, rad) or
"invalid"; with ``--pixels`` "row,col": the step's fractional row and the
lower surface's fitted column there.  ``--record FILE`` in live mode writes
the frames in that format.

The calibration defaults to :class:`MvsCalibration`'s; ``--calib FILE`` reads
a TOML file whose keys (top level or under ``[calibration]``) are its fields.

In a cell::

    droid-mvs [--cell FILE] mvs

takes the board, the serial port, the baud rate and the calibration from the
cell file's ``[subunits.mvs]`` (``dsp``, ``sensor_serial``, ``baud``,
``[subunits.mvs.calibration]``, ``board_wait``, ``stamp``); options given on the command
line win.  It waits up to ``board_wait`` seconds (default 20) for the DSP
board and the serial port to appear -- droid-sim creates both, started in
parallel by ``droid-cell up`` -- then completes the readiness handshake and
keeps a presence record ``/droid.<cell>.proc.mvs-<name>`` like every program.
A serial port that fails in a cell (droid-sim restarted) is reopened, one try
a frame, instead of ending the program.
"""
from __future__ import annotations

import argparse
import re
import signal
import sys
import threading
import time

import numpy as np

from droid.brain.cell.registry import open_url
from droid.brain.plumbing.serial_port import PortLink
from droid.cli import (ArgumentParser, BadInput, MAX_WAIT_S, RuntimeFailure, baud_rate, bounded_float, bounded_int,
                       duration_s, file_number, read_toml, run)
from droid.numbers import Range
from droid.subunits.mvs.calibration import MvsCalibration
from droid.brain.plumbing.sensor_line import stamp_ms_of
from droid.subunits.mvs.protocol import format_line
from droid.subunits.mvs.station import MvsStation, SensorCore
from droid.subunits.mvs.wire import COLUMNS, DEFAULT_BAUD, FRAME_RATE_HZ, MIN_BAUD, NO_STRIPE, ROWS

PROG = "droid-mvs"
#: How long a sensor in a cell waits for its board and serial port by default [s].
CELL_WAIT_S = 20.0
#: Poll period while waiting for the board or the serial port to appear [s].
APPEAR_POLL_S = 0.05
#: Give up on one serial write after a frame period [s]: when the line is
#: congested (the Brain is not reading) lines are dropped, the loop keeps pace.
WRITE_TIMEOUT_S = 1.0 / FRAME_RATE_HZ
_INTEGER = re.compile(r"[+-]?[0-9]+")


def load_calibration(path: str | None) -> MvsCalibration:
    """The calibration from ``--calib FILE``, or the defaults."""
    if path is None:
        return MvsCalibration()
    data = read_toml(path, "calibration")
    table = data.get("calibration", data)
    if not isinstance(table, dict):
        raise BadInput(f"calibration {path}: [calibration] must be a table")
    return MvsCalibration.from_table(table, source=f"calibration {path}")


def parse_frame_line(text: str, where: str) -> np.ndarray | None:
    """One replay line -> int16 (240,) columns; None for a blank or '#' line; BadInput otherwise."""
    body = text.strip()
    if not body or body.startswith("#"):
        return None
    fields = body.split()
    if len(fields) != ROWS:
        raise BadInput(f"{where}: expected {ROWS} integers, got {len(fields)}")
    for field in fields:
        if not _INTEGER.fullmatch(field):
            raise BadInput(f"{where}: not an integer: {field[:20]!r}")
    values = [int(f) for f in fields]
    too_big = [v for v in values if v >= COLUMNS]
    if too_big:
        raise BadInput(f"{where}: column {too_big[0]} beyond {COLUMNS - 1}")
    return np.array([max(v, NO_STRIPE) for v in values], dtype=np.int16)


def format_frame_line(rows: np.ndarray) -> str:
    """A frame as a replay line (240 integers)."""
    return " ".join(str(int(v)) for v in rows)


def replay(source: str, core: SensorCore, pixels: bool, out=None) -> None:
    """Process recorded frames from a file (or '-' for stdin), one result a line to ``out``."""
    out = out or sys.stdout
    name = "<stdin>" if source == "-" else source
    try:
        stream = sys.stdin if source == "-" else open(source, encoding="ascii", errors="replace")
    except OSError as exc:
        raise BadInput(f"cannot open {source}: {exc.strerror}") from None
    try:
        for lineno, text in enumerate(stream, 1):
            rows = parse_frame_line(text, f"{name}:{lineno}")
            if rows is None:
                continue
            feature = core.process(rows)
            if feature is None:
                out.write("invalid\n")
            elif pixels:
                out.write(f"{feature.row:.3f},{feature.column:.3f}\n")
            else:
                out.write(format_line(feature).decode())
    finally:
        if stream is not sys.stdin:
            stream.close()


def _open_serial_waiting(link: PortLink, url: str, wait_s: float, stop: threading.Event) -> bool:
    """Open the port, retrying for up to ``wait_s`` [s] while it is not there yet (False if stopped)."""
    deadline = time.monotonic() + wait_s
    while not stop.is_set():
        if link.open():
            return True
        if time.monotonic() >= deadline:
            why = f"cannot open serial {url}: {link.last_error}"
            if wait_s > 0:
                raise RuntimeFailure(f"{why} (waited {wait_s:g} s; is droid-sim running?)")
            raise RuntimeFailure(why)
        stop.wait(APPEAR_POLL_S)
    return False


def _open_board(url: str, wait_s: float, stop: threading.Event):
    """Open the DSP board, waiting for up to ``wait_s`` [s] for it to appear (None if stopped)."""
    deadline = time.monotonic() + wait_s
    while not stop.is_set():
        try:
            return open_url(url, "dsp")  # droid.subunits.mvs.dsp.open_dsp, by the registry
        except RuntimeFailure as exc:
            if time.monotonic() >= deadline:
                if wait_s > 0 and "not present" in str(exc):
                    raise RuntimeFailure(f"{exc} after waiting {wait_s:g} s (is droid-sim running?)") from None
                raise
            stop.wait(APPEAR_POLL_S)
    return None


def live(args, core: SensorCore, ready=None, beat=None, reopen: bool = False) -> int:
    """The sensor loop: retrace -> :class:`MvsStation` (extract, the line, the port) (see the module docstring).

    The station holds the cycle and its rules (the timeout, counted in frame periods, and
    the port's reopening); this shell waits for the retrace, keeps the clock, the recording,
    the signals and the report.  ``ready()`` is called once the board and the port are
    open; ``beat(frames, overruns)`` once a frame (both optional: the cell's handshake and
    presence).  With ``reopen`` a serial port that fails is closed and reopened (one try a
    frame, the lines meanwhile dropped and counted) instead of ending the run.
    """
    wait_s = max(0.0, args.board_wait)
    deadline = time.monotonic() + wait_s
    stop = threading.Event()
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    record = board = None
    # the cell's one serial port (droid.brain.plumbing.serial_port): a write that times out is an
    # overrun (the line is slower than the frames), any other error closes the port
    port = PortLink(open_url(args.serial, "serial", baud=args.baud, write_timeout_s=WRITE_TIMEOUT_S),
                    write_timeout_keeps_open=True)
    # --retrace-timeout [s] as frame periods: a wait that times out is one whole timeout
    station = MvsStation(core, port, timeout_frames=args.retrace_timeout * FRAME_RATE_HZ, reopen=reopen)
    t0 = time.monotonic()
    try:
        board = _open_board(args.dsp, wait_s, stop)
        _open_serial_waiting(port, args.serial, max(0.0, deadline - time.monotonic()), stop)
        if args.record:
            try:
                record = open(args.record, "w")
            except OSError as exc:
                raise BadInput(f"cannot write {args.record}: {exc.strerror}") from None
        if ready is not None and not stop.is_set():
            ready()
        t0 = time.monotonic()
        while not stop.is_set() and (args.count is None or core.frames < args.count):
            frame = board.wait_frame(args.retrace_timeout)
            t_frame_ns = time.monotonic_ns()  # the retrace: the frame's capture, on the cell's clock
            if stop.is_set():
                break
            if frame is None:
                out = station.on_wait(station.timeout_frames)
            else:
                if record is not None:
                    try:
                        record.write(format_frame_line(frame.rows) + "\n")
                    except OSError as exc:
                        raise RuntimeFailure(f"cannot write {args.record}: {exc.strerror}") from None
                stamp_ms = stamp_ms_of(t_frame_ns) if getattr(args, "stamp", False) else None
                out = station.on_frame(frame.rows, stamp_ms, frame.missed)
            if out.fatal:
                raise RuntimeFailure(f"serial {args.serial}: {out.port_error}")
            if out.port_error is not None:
                print(f"{PROG}: serial {args.serial}: {out.port_error}; reopening", file=sys.stderr, flush=True)
            if beat is not None:
                beat(core.frames, port.write_timeouts + station.timeouts + station.lost)
    finally:
        elapsed = max(time.monotonic() - t0, 1e-9)
        for sig, old in handlers.items():
            signal.signal(sig, old)
        if record is not None:
            record.close()
        port.close()
        if board is not None:
            board.close()
    reopen_note = f", {station.lost} lines lost with the port, {station.reopened} reopens" if reopen else ""
    print(f"{PROG}: {core.frames} frames in {elapsed:.2f} s = {core.frames / elapsed:.1f} frames/s "
          f"({core.valid} valid, {core.invalid} invalid, {station.missed} missed, {station.timeouts} retrace "
          f"timeouts, {port.write_timeouts} serial overruns{reopen_note})", file=sys.stderr)
    return 0


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog=PROG, description="MVS line-laser sensor program (thesis 5.4): "
                            "DSP frames -> lap-joint feature -> 'x,y,roll' lines over serial.")
    parser.add_argument("subunit", nargs="?", help="run as this subunit of the cell (e.g. mvs): "
                        "board, port, baud and calibration from [subunits.NAME]")
    parser.add_argument("--cell", metavar="FILE", default=None,
                        help="cell file (with a subunit; default: $DROID_CELL, else the built-in simulated cell)")
    parser.add_argument("--ready-fd", type=bounded_int(0, 1 << 20), default=None, help=argparse.SUPPRESS)
    parser.add_argument("--dsp", metavar="URL", help="DSP board: shm://NAME or inproc://NAME")
    parser.add_argument("--serial", metavar="URL", help="serial port URL or device (pyserial serial_for_url)")
    parser.add_argument("--baud", type=baud_rate(MIN_BAUD), default=None,
                        help=f"baud rate (default {DEFAULT_BAUD})")
    parser.add_argument("--count", type=bounded_int(1, 10**12, "frames"), help="stop after N frames")
    parser.add_argument("--retrace-timeout", type=duration_s(60.0), default=6 / FRAME_RATE_HZ, metavar="S",
                        help="send 'invalid' when no retrace comes within S seconds (default 0.1)")
    parser.add_argument("--board-wait", type=bounded_float(0.0, MAX_WAIT_S, "s"), default=None, metavar="S",
                        help="wait up to S seconds for the DSP board (and in a cell the serial port) "
                        f"to appear (default 5; in a cell {CELL_WAIT_S:g})")
    parser.add_argument("--record", metavar="FILE", help="also write each frame to FILE (replay format)")
    parser.add_argument("--stamp", action="store_true",
                        help="append each frame's capture stamp (CLOCK_MONOTONIC ms mod 100000) to its line "
                             "(issue 12; only where the Brain shares this host's clock)")
    parser.add_argument("--replay", metavar="FILE", help="process recorded frames from FILE ('-' = stdin)")
    parser.add_argument("--pixels", action="store_true", help="with --replay: print 'row,col' of the step")
    parser.add_argument("--calib", metavar="FILE", help="calibration TOML (keys of MvsCalibration)")
    return parser


def apply_cell(args):
    """Fill unset live options from the cell file's ``[subunits.NAME]``; returns (cell, subunit)."""
    from droid.brain.cell.cellfile import load_cell
    from droid.brain.runtime.program import use_cell

    cell = load_cell(args.cell)
    use_cell(cell)
    sub = cell.subunit(args.subunit)
    where = f"{cell.path}: [subunits.{sub.name}]"
    if sub.cls != "line_laser":
        raise BadInput(f"{where} is class {sub.cls!r}, not a line_laser sensor")
    opts = sub.options

    def option(key, typ, default=None):
        val = opts.get(key, default)
        if typ is float and isinstance(val, int) and not isinstance(val, bool):
            val = float(val)
        if val is not None and (not isinstance(val, typ) or isinstance(val, bool)):
            raise BadInput(f"{where} {key} must be {typ.__name__}, got {val!r}")
        return val

    args.dsp = args.dsp or option("dsp", str)
    args.serial = args.serial or option("sensor_serial", str)
    if args.baud is None:
        args.baud = file_number(opts.get("baud", DEFAULT_BAUD), baud_rate(MIN_BAUD), where, "baud")
    if args.board_wait is None:
        args.board_wait = file_number(opts.get("board_wait", CELL_WAIT_S), Range(0.0, MAX_WAIT_S, "s"), where,
                                      "board_wait")
    stamp = opts.get("stamp", False)
    if not isinstance(stamp, bool):
        raise BadInput(f"{where} stamp must be true or false, got {stamp!r}")
    args.stamp = args.stamp or stamp
    if not args.dsp or not args.serial:
        raise BadInput(f"{where} needs dsp = \"<board URL>\" and sensor_serial = \"<port>\" for droid-mvs")
    return cell, sub


def cell_calibration(sub, where: str) -> MvsCalibration:
    table = sub.options.get("calibration", {})
    if not isinstance(table, dict):
        raise BadInput(f"{where} calibration must be a table")
    return MvsCalibration.from_table(table, source=f"{where} calibration")


@run
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.replay is not None:
        if args.dsp or args.serial or args.record or args.count or args.subunit or args.cell or args.stamp:
            raise BadInput("--replay takes no --dsp, --serial, --record, --count, --stamp, --cell or subunit")
        replay(args.replay, SensorCore(load_calibration(args.calib)), args.pixels)
        return 0
    if args.pixels:
        raise BadInput("--pixels needs --replay")
    cell = sub = None
    if args.subunit is not None or args.cell is not None:
        args.subunit = args.subunit or "mvs"
        cell, sub = apply_cell(args)
        calib = load_calibration(args.calib) if args.calib else \
            cell_calibration(sub, f"{cell.path}: [subunits.{sub.name}]")
    else:
        calib = load_calibration(args.calib)
        if args.baud is None:
            args.baud = DEFAULT_BAUD
        if args.board_wait is None:
            args.board_wait = 5.0
    if not args.dsp or not args.serial:
        raise BadInput("live mode needs --dsp URL and --serial URL (or --replay FILE, or a cell subunit)")
    if args.baud < MIN_BAUD:
        raise BadInput(f"--baud {args.baud} cannot carry {FRAME_RATE_HZ:g} lines/s (needs >= {MIN_BAUD})")
    core = SensorCore(calib)
    if cell is None:
        return live(args, core)
    return live_in_cell(args, core, cell, sub)


def live_in_cell(args, core: SensorCore, cell, sub) -> int:
    """:func:`live` with the cell's readiness handshake and presence record."""
    from droid.brain.runtime.program import Presence, notify_ready, presence_key
    from droid.brain.runtime.rt import try_sched_fifo

    # In a cell that asks for SCHED_FIFO the sensor is part of the tracking loop's chain
    # (frame -> line -> Brain Status -> droid-seamtrack, §5.4): below the Brain's programs.
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
    failed = True

    def ready() -> None:
        presence.ready()
        notify_ready(args.ready_fd)

    def beat(frames: int, overruns: int) -> None:
        presence.beat(0, frames, overruns)

    try:
        code = live(args, core, ready, beat, reopen=True)
        failed = False
        return code
    finally:
        presence.close(failed=failed)


if __name__ == "__main__":
    sys.exit(main())
