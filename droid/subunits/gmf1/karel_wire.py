"""The KAREL serial server protocol of the GM Fanuc S400 (thesis §4.2.1, §4.2.4): one module.

The thesis's serial program sends "ASCII characters separated by whitespaces"
to a KAREL server on the controller, which "translates the data into
cartesian move commands".  The exact grammar is ours (the thesis does not
print it); both ends use this module: droid-gmf1-serial formats requests and
parses replies, the simulated controller (droid-sim) parses requests and
formats replies.

Requests (host -> controller), one line each, fields separated by one or more
spaces or tabs, terminated by CR (a LF is ignored)::

    MOVE  id x y z a b c [t]    wrist-centre pose in the robot's BASE frame:
                                x y z [mm], Z-Y-Z Euler angles a b c [deg]
                                (droid.kinematics.transforms, eq. 4.2);
                                t: shortest duration wanted [s] (optional)
    JMOVE id j1 j2 j3 j4 j5 j6 [t]   joint angles [deg] (the D-H joint variables)
    HOME  id                    go to the joint-zero home pose
    STAT  id                    report the state
    HALT  id                    stop the motion in progress along its path at the
                                controller's deceleration (issue 41: the collision
                                guard's protective stop); taken at once, also
                                inside the interpreter's cycle and while moving

Replies (controller -> host), terminated by CR LF::

    ACK  id seconds             accepted: the motion takes ``seconds`` [s]
    DONE id                     motion ``id`` finished
    BUSY id                     rejected: the interpreter is still in its cycle,
                                or a motion is in progress (MOVE/JMOVE/HOME)
    ERR  id code                rejected: code is one of ERR_CODES
                                (id 0 when the request's id was unreadable)
    STAT id IDLE|MOVING mid     state, and the id of the current or last motion
                                (0: none since power-up)

A HALT is answered ``ACK id seconds`` (the time until the arm stands; 0 when idle);
the halted motion's own ``DONE mid`` follows when it stands.

``id`` is a decimal integer 1..4294967295 chosen by the host (the serial
program uses the Brain's ``cmd_id``; STAT probes use their own counter).
Numbers are plain decimals: an optional sign, digits, an optional point and
digits; no exponent, no nan/inf, at most :data:`MAX_NUMBER_CHARS` characters.
A line longer than :data:`MAX_LINE` bytes is rejected (``ERR 0 LONG``).

Every parser here takes arbitrary bytes and either returns a value or raises
:class:`WireError` (a one-line reason); nothing else escapes (property-tested).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from droid.brain.plumbing.serial_line import BITS_PER_BYTE  # noqa: F401  (kw.BITS_PER_BYTE for its users)
from droid.brain.plumbing.serial_line import LineSplitter as _SerialLineSplitter

# -- line format ---------------------------------------------------------------
BAUD = 9600  # thesis §4.2.4: "a RS-232 25-pin serial port which has a bandwidth of 9600 bps"
# BITS_PER_BYTE (8N1: start + 8 data + stop) is droid.brain.plumbing.serial_line's, imported above
REQUEST_END = b"\r"
REPLY_END = b"\r\n"
MAX_LINE = 120  # bytes, terminator excluded (a KAREL STRING buffer)
#: The slowest line accepted [baud] (droid-gmf1-serial --baud, [subunits.X] baud): the lowest
#: standard rate (droid.numbers.STANDARD_BAUDS) at which a longest request and a longest reply
#: (2 x 121 bytes x 10 bits = 2420 bits) cross the line within the default 1 s reply timeout.
#: 2400 baud cannot (1.008 s); the thesis's line is 9600 baud (§4.2.4).
MIN_BAUD = 4800
MAX_NUMBER_CHARS = 14
MAX_ID = 0xFFFFFFFF

# -- verbs and replies -----------------------------------------------------------
MOVE = "MOVE"
JMOVE = "JMOVE"
HOME = "HOME"
STAT = "STAT"
HALT = "HALT"  # issue 41: the protective stop of a move in flight
VERBS = (MOVE, JMOVE, HOME, STAT, HALT)
MOTION_VERBS = (MOVE, JMOVE, HOME)

ACK = "ACK"
DONE = "DONE"
BUSY = "BUSY"
ERR = "ERR"
REPLY_KINDS = (ACK, DONE, BUSY, ERR, STAT)

ERR_SYNTAX = "SYNTAX"  # not a request of this grammar
ERR_RANGE = "RANGE"  # unreachable, or outside the joint limits
ERR_LONG = "LONG"  # line longer than MAX_LINE
ERR_OVERRUN = "OVERRUN"  # bytes lost: the receive buffer overflowed
ERR_CODES = (ERR_SYNTAX, ERR_RANGE, ERR_LONG, ERR_OVERRUN)

IDLE = "IDLE"
MOVING = "MOVING"
STATES = (IDLE, MOVING)

MAX_DURATION_S = 3600.0  # a longer t is refused as SYNTAX
MAX_ABS_MM = 100000.0
MAX_ABS_DEG = 3600.0

_NUMBER = re.compile(rb"^[+-]?(?:\d+(?:\.\d*)?|\.\d+)$")
_ID = re.compile(rb"^\d{1,10}$")
_SEP = re.compile(rb"[ \t]+")


class WireError(ValueError):
    """A line that does not follow the grammar; ``code`` is an ERR_* code, ``cmd_id`` the id if read."""

    def __init__(self, reason: str, code: str = ERR_SYNTAX, cmd_id: int = 0):
        super().__init__(reason)
        self.code = code
        self.cmd_id = cmd_id


# -- requests ------------------------------------------------------------------------
@dataclass(frozen=True)
class Request:
    """A parsed request.  ``values``: 6 numbers for MOVE [mm, deg] / JMOVE [deg], else ()."""

    verb: str
    cmd_id: int
    values: tuple[float, ...] = ()
    duration_s: float | None = None


def _number(tok: bytes, what: str, cmd_id: int) -> float:
    if len(tok) > MAX_NUMBER_CHARS or not _NUMBER.match(tok):
        raise WireError(f"{what}: not a plain decimal number: {tok[:20]!r}", ERR_SYNTAX, cmd_id)
    return float(tok)


def _parse_id(tok: bytes) -> int:
    if not _ID.match(tok):
        raise WireError(f"bad id {tok[:20]!r}: expected 1..{MAX_ID}")
    v = int(tok)
    if not 1 <= v <= MAX_ID:
        raise WireError(f"id {v} outside 1..{MAX_ID}")
    return v


def fields(line: bytes) -> list[bytes]:
    """Whitespace-separated fields of one line (terminators already removed)."""
    return [f for f in _SEP.split(line.strip(b" \t")) if f]


def _word(field: bytes, what: str, known: tuple, hint: str, unknown: str | None = None) -> str:
    """The first field of a request or reply as one of ``known``; WireError otherwise."""
    try:
        word = field.decode("ascii")
    except UnicodeDecodeError:
        raise WireError(f"{what} is not ASCII") from None
    if word not in known:
        raise WireError(f"{unknown or 'unknown ' + what} {word[:12]!r}{hint}")
    return word


def parse_request(line: bytes) -> Request:
    """Parse one request line (without its terminator).  Raises :class:`WireError`."""
    if len(line) > MAX_LINE:
        raise WireError(f"line of {len(line)} bytes is longer than {MAX_LINE}", ERR_LONG)
    f = fields(line)
    if not f:
        raise WireError("empty line")
    verb = _word(f[0], "verb", VERBS, f" (known: {', '.join(VERBS)})")
    if len(f) < 2:
        raise WireError(f"{verb} needs an id")
    cmd_id = _parse_id(f[1])
    args = f[2:]
    if verb in (HOME, STAT, HALT):
        if args:
            raise WireError(f"{verb} takes only an id", ERR_SYNTAX, cmd_id)
        return Request(verb, cmd_id)
    if len(args) not in (6, 7):
        raise WireError(f"{verb} needs 6 values and an optional duration, got {len(args)}", ERR_SYNTAX, cmd_id)
    vals = tuple(_number(t, verb, cmd_id) for t in args[:6])
    lim = (MAX_ABS_MM,) * 3 + (MAX_ABS_DEG,) * 3 if verb == MOVE else (MAX_ABS_DEG,) * 6
    for v, m in zip(vals, lim):
        if abs(v) > m:
            raise WireError(f"{verb}: value {v:g} beyond +-{m:g}", ERR_RANGE, cmd_id)
    dur = None
    if len(args) == 7:
        dur = _number(args[6], "duration", cmd_id)
        if not 0.0 <= dur <= MAX_DURATION_S:
            raise WireError(f"duration {dur:g} s outside 0..{MAX_DURATION_S:g}", ERR_SYNTAX, cmd_id)
    return Request(verb, cmd_id, vals, dur)


def _fmt(v: float) -> str:
    if not math.isfinite(v):
        raise ValueError(f"cannot send a non-finite number {v!r}")
    s = f"{v:.3f}"
    return "0.000" if s == "-0.000" else s


def _check_id(cmd_id: int) -> int:
    cmd_id = int(cmd_id)
    if not 1 <= cmd_id <= MAX_ID:
        raise ValueError(f"id {cmd_id} outside 1..{MAX_ID}")
    return cmd_id


def format_move(cmd_id: int, pose, duration_s: float | None = None) -> bytes:
    """``MOVE id x y z a b c [t]\\r``: pose = x y z [mm], ZYZ a b c [deg] in the robot BASE frame."""
    return _format_motion(MOVE, cmd_id, pose, duration_s)


def format_jmove(cmd_id: int, joints_deg, duration_s: float | None = None) -> bytes:
    """``JMOVE id j1..j6 [t]\\r``: joint angles [deg]."""
    return _format_motion(JMOVE, cmd_id, joints_deg, duration_s)


def _format_motion(verb: str, cmd_id: int, vals, duration_s: float | None) -> bytes:
    vals = [float(v) for v in vals]
    if len(vals) != 6:
        raise ValueError(f"{verb} needs 6 values")
    parts = [verb, str(_check_id(cmd_id))] + [_fmt(v) for v in vals]
    if duration_s is not None:
        parts.append(_fmt(min(max(float(duration_s), 0.0), MAX_DURATION_S)))
    line = " ".join(parts).encode("ascii")
    if len(line) > MAX_LINE:
        raise ValueError(f"{verb} line of {len(line)} bytes exceeds {MAX_LINE} (values out of range?)")
    return line + REQUEST_END


def format_home(cmd_id: int) -> bytes:
    return f"{HOME} {_check_id(cmd_id)}".encode("ascii") + REQUEST_END


def format_stat(cmd_id: int) -> bytes:
    return f"{STAT} {_check_id(cmd_id)}".encode("ascii") + REQUEST_END


def format_halt(cmd_id: int) -> bytes:
    return f"{HALT} {_check_id(cmd_id)}".encode("ascii") + REQUEST_END


# -- replies ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Reply:
    """A parsed reply.  ``seconds`` for ACK, ``code`` for ERR, ``state``/``motion_id`` for STAT."""

    kind: str
    cmd_id: int
    seconds: float = 0.0
    code: str = ""
    state: str = ""
    motion_id: int = 0


def parse_reply(line: bytes) -> Reply:
    """Parse one reply line (without its terminator).  Raises :class:`WireError`."""
    if len(line) > MAX_LINE:
        raise WireError(f"reply of {len(line)} bytes is longer than {MAX_LINE}", ERR_LONG)
    f = fields(line)
    if len(f) < 2:
        raise WireError(f"reply {line[:20]!r} has fewer than 2 fields")
    kind = _word(f[0], "reply kind", REPLY_KINDS, "", unknown="unknown reply")
    if kind == ERR and f[1] == b"0":
        cmd_id = 0
    else:
        cmd_id = _parse_id(f[1])
    args = f[2:]
    if kind == ACK:
        if len(args) != 1:
            raise WireError("ACK needs id and seconds")
        secs = _number(args[0], "ACK seconds", cmd_id)
        if secs > MAX_DURATION_S:
            raise WireError(f"ACK seconds {secs:g} beyond {MAX_DURATION_S:g}")
        return Reply(kind, cmd_id, seconds=secs)
    if kind in (DONE, BUSY):
        if args:
            raise WireError(f"{kind} takes only an id")
        return Reply(kind, cmd_id)
    if kind == ERR:
        code = args[0].decode("ascii", "replace") if len(args) == 1 else ""
        if code not in ERR_CODES:
            raise WireError(f"ERR with unknown code {code[:12]!r}")
        return Reply(kind, cmd_id, code=code)
    # STAT id state mid
    if len(args) != 2:
        raise WireError("STAT reply needs id, state and motion id")
    state = args[0].decode("ascii", "replace")
    if state not in STATES:
        raise WireError(f"STAT state {state[:12]!r} unknown")
    mid = 0 if args[1] == b"0" else _parse_id(args[1])
    return Reply(kind, cmd_id, state=state, motion_id=mid)


def format_reply(r: Reply) -> bytes:
    if r.kind == ACK:
        text = f"{ACK} {r.cmd_id} {_fmt(r.seconds)}"
    elif r.kind in (DONE, BUSY):
        text = f"{r.kind} {r.cmd_id}"
    elif r.kind == ERR:
        text = f"{ERR} {r.cmd_id} {r.code}"
    elif r.kind == STAT:
        text = f"{STAT} {r.cmd_id} {r.state} {r.motion_id}"
    else:
        raise ValueError(f"unknown reply kind {r.kind!r}")
    return text.encode("ascii") + REPLY_END


# -- splitting a byte stream into lines ---------------------------------------------------------
class LineSplitter(_SerialLineSplitter):
    """The KAREL line splitter: CR or LF ends a line, empty lines are skipped.

    A partial line longer than :data:`MAX_LINE` is returned at once (cut to
    ``MAX_LINE + 1`` bytes, so the parser answers LONG), the rest of it is
    thrown away up to its end, and ``overlong`` counts it.  The one splitter
    of the cell's serial lines (:class:`droid.brain.plumbing.serial_line.LineSplitter`)
    with the KAREL policy.
    """

    def __init__(self, max_line: int = MAX_LINE) -> None:
        super().__init__(max_line, b"\r\n", skip_empty=True, early_overlong=True)
        self.max_line = max_line
