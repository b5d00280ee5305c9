"""droid-mvs: the MVS sensor program (thesis §5.4, sensor.exe).

Live::

    droid-mvs --dsp shm://droid.sim.mvs.dsp --serial /dev/ttyS0 [--baud 19200] [--count N]

waits for each vertical retrace of the DSP board (timeout ``--retrace-timeout``),
copies the 240 stripe columns, extracts the lap-joint feature and writes one
line "x,y,roll\\n" (or "invalid\\n") to the serial URL at the frame rate, 60 Hz.
A retrace that does not come in time also sends "invalid".  On SIGINT,
SIGTERM or after ``--count`` frames it stops and reports the frames
processed per second on stderr, as sensor.exe did on exit.

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
"""
from __future__ import annotations

import re
import signal
import sys
import threading
import time
import tomllib
from dataclasses import dataclass

import numpy as np
import serial

from droid.cli import ArgumentParser, BadInput, RuntimeFailure, positive_float, positive_int, run
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.dsp import open_dsp
from droid.subunits.mvs.feature import Feature, FeatureParams, extract
from droid.subunits.mvs.protocol import format_line
from droid.subunits.mvs.wire import COLUMNS, DEFAULT_BAUD, FRAME_RATE_HZ, MIN_BAUD, NO_STRIPE, ROWS

PROG = "droid-mvs"
#: Give up on one serial write after this long [s] (the Brain is not reading).
WRITE_TIMEOUT_S = 0.5
_INTEGER = re.compile(r"[+-]?[0-9]+")


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

    def step(self, rows: np.ndarray) -> bytes:
        """One frame -> the line to send ("x,y,roll\\n" or "invalid\\n")."""
        return format_line(self.process(rows))

    @property
    def invalid(self) -> int:
        return self.frames - self.valid


def load_calibration(path: str | None) -> MvsCalibration:
    """The calibration from ``--calib FILE``, or the defaults."""
    if path is None:
        return MvsCalibration()
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise BadInput(f"calibration {path}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise BadInput(f"calibration {path}: not valid TOML: {exc}") from None
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


def replay(source: str, core: SensorCore, pixels: bool, out=sys.stdout) -> None:
    """Process recorded frames from a file (or '-' for stdin), one result a line."""
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


def _open_serial(url: str, baud: int):
    try:
        return serial.serial_for_url(url, baudrate=baud, write_timeout=WRITE_TIMEOUT_S)
    except ValueError as exc:
        raise BadInput(f"serial {url}: {exc}") from None
    except serial.SerialException as exc:
        raise RuntimeFailure(f"cannot open serial {url}: {exc}") from None


def live(args, core: SensorCore) -> int:
    """The sensor loop: retrace -> copy -> extract -> serial line (see the module docstring)."""
    board = open_dsp(args.dsp, wait_s=args.board_wait)
    stop = threading.Event()
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    record = None
    timeouts = missed = overruns = 0
    port = None
    t0 = time.monotonic()
    try:
        port = _open_serial(args.serial, args.baud)
        record = open(args.record, "w") if args.record else None
        t0 = time.monotonic()
        while not stop.is_set() and (args.count is None or core.frames < args.count):
            frame = board.wait_frame(args.retrace_timeout)
            if stop.is_set():
                break
            if frame is None:
                timeouts += 1
                line = format_line(None)
            else:
                missed += frame.missed
                line = core.step(frame.rows)
                if record is not None:
                    record.write(format_frame_line(frame.rows) + "\n")
            try:
                port.write(line)
            except serial.SerialTimeoutException:
                overruns += 1
            except serial.SerialException as exc:
                raise RuntimeFailure(f"serial {args.serial}: {exc}") from None
    except OSError as exc:
        raise RuntimeFailure(f"{exc.filename or 'I/O'}: {exc.strerror}") from None
    finally:
        elapsed = max(time.monotonic() - t0, 1e-9)
        for sig, old in handlers.items():
            signal.signal(sig, old)
        if record is not None:
            record.close()
        if port is not None:
            port.close()
        board.close()
    print(f"{PROG}: {core.frames} frames in {elapsed:.2f} s = {core.frames / elapsed:.1f} frames/s "
          f"({core.valid} valid, {core.invalid} invalid, {missed} missed, {timeouts} retrace timeouts, "
          f"{overruns} serial overruns)", file=sys.stderr)
    return 0


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog=PROG, description="MVS line-laser sensor program (thesis 5.4): "
                            "DSP frames -> lap-joint feature -> 'x,y,roll' lines over serial.")
    parser.add_argument("--dsp", metavar="URL", help="DSP board: shm://NAME or inproc://NAME")
    parser.add_argument("--serial", metavar="URL", help="serial port URL or device (pyserial serial_for_url)")
    parser.add_argument("--baud", type=positive_int, default=DEFAULT_BAUD,
                        help=f"baud rate, >= {MIN_BAUD} (default {DEFAULT_BAUD})")
    parser.add_argument("--count", type=positive_int, help="stop after N frames")
    parser.add_argument("--retrace-timeout", type=positive_float, default=6 / FRAME_RATE_HZ, metavar="S",
                        help="send 'invalid' when no retrace comes within S seconds (default 0.1)")
    parser.add_argument("--board-wait", type=float, default=5.0, metavar="S",
                        help="wait up to S seconds for the DSP board to appear (default 5)")
    parser.add_argument("--record", metavar="FILE", help="also write each frame to FILE (replay format)")
    parser.add_argument("--replay", metavar="FILE", help="process recorded frames from FILE ('-' = stdin)")
    parser.add_argument("--pixels", action="store_true", help="with --replay: print 'row,col' of the step")
    parser.add_argument("--calib", metavar="FILE", help="calibration TOML (keys of MvsCalibration)")
    return parser


@run
def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    core = SensorCore(load_calibration(args.calib))
    if args.replay is not None:
        if args.dsp or args.serial or args.record or args.count:
            parser.error("--replay takes no --dsp, --serial, --record or --count")
        replay(args.replay, core, args.pixels)
        return 0
    if args.pixels:
        parser.error("--pixels needs --replay")
    if not args.dsp or not args.serial:
        parser.error("live mode needs --dsp URL and --serial URL (or --replay FILE)")
    if args.baud < MIN_BAUD:
        parser.error(f"--baud {args.baud} cannot carry {FRAME_RATE_HZ:g} lines/s (needs >= {MIN_BAUD})")
    return live(args, core)


if __name__ == "__main__":
    sys.exit(main())
