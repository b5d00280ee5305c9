"""Joystick drivers: a Linux joystick device read by URL (thesis §2.6 Figure 2.10, §3.4).

The thesis's Brain read a modified Thrustmaster analog joystick (2 analog
axes, 8 digital inputs) through a CIO-DAS08 data-acquisition board.  Here a
joystick is any Linux input device, chosen by URL in the cell file
(``device = ...`` of a ``joystick`` subunit), as pyserial chooses a port:

``js:///dev/input/js0``
    the Linux joystick API: 8-byte ``struct js_event`` records
    (``u32 time [ms], s16 value, u8 type, u8 number``; type 0x01 button,
    0x02 axis, | 0x80 for the initial state the kernel sends at open).
    Axis values -32767..32767 map to -1..1.
``evdev:///dev/input/event3``
    the event interface: 24-byte ``struct input_event`` records (64-bit
    ``timeval``, ``u16 type, u16 code, s32 value``); EV_ABS codes 0..7
    (ABS_X .. ABS_RUDDER) are axes 0..7, scaled by the device's own range
    (ioctl EVIOCGABS; ``min``/``max`` options where the ioctl does not work);
    EV_KEY codes BTN_JOYSTICK (0x120) .. 0x12f and BTN_GAMEPAD (0x130) ..
    0x13f are buttons 0..15.

Options follow ``?``: ``evdev:///dev/input/event3?min=0&max=255``.  An
unknown scheme or option is refused with the expected form (exit 2).

droid-sim's twin (:mod:`droid.sim.joystick.device`) writes js_event records into a
pseudo-terminal published at a path, so the simulated cell uses
``js://{run}/joy.js``: the same driver, the same bytes.

:class:`JoystickState` is the core (events in, axes and buttons out, no I/O);
:class:`JoystickDevice` the I/O: it opens the path non-blocking, reads
whatever is waiting each poll, and on an I/O error (unplugged, the twin gone)
closes, marks the state invalid and reopens on a later poll.
"""
from __future__ import annotations

import errno
import fcntl
import os
import struct
from urllib.parse import parse_qsl, urlsplit

from droid.brain.db.layouts import JOYSTICK_AXES, JOYSTICK_BUTTONS
from droid.cli import BadInput

# --- Linux joystick API (linux/joystick.h)
JS_EVENT = struct.Struct("<IhBB")  # time [ms], value, type, number
JS_EVENT_BUTTON = 0x01
JS_EVENT_AXIS = 0x02
JS_EVENT_INIT = 0x80
JS_AXIS_MAX = 32767

# --- evdev (linux/input.h, linux/input-event-codes.h), 64-bit struct timeval
INPUT_EVENT = struct.Struct("<qqHHi")  # tv_sec, tv_usec, type, code, value
EV_SYN = 0x00
EV_KEY = 0x01
EV_ABS = 0x03
BTN_JOYSTICK = 0x120
BTN_GAMEPAD = 0x130
_ABSINFO = struct.Struct("<6i")  # value, minimum, maximum, fuzz, flat, resolution


def _eviocgabs(code: int) -> int:
    """ioctl number of EVIOCGABS(code) = _IOR('E', 0x40 + code, struct input_absinfo)."""
    return (2 << 30) | (_ABSINFO.size << 16) | (ord("E") << 8) | (0x40 + code)


#: Most bytes read from a device in one poll.
READ_CHUNK_BYTES = 4096


class JoystickState:
    """Axes [-1, 1] and buttons (0/1) of one joystick, from its events (no I/O)."""

    def __init__(self) -> None:
        self.axes = [0.0] * JOYSTICK_AXES
        self.buttons = [0] * JOYSTICK_BUTTONS
        self.n_axes = 0
        self.n_buttons = 0
        self.events = 0
        self.ignored = 0  # events for axes/buttons beyond the record, or of unknown type
        self.valid = False

    def axis(self, number: int, value: float) -> None:
        if 0 <= number < JOYSTICK_AXES:
            self.axes[number] = max(-1.0, min(1.0, value))
            self.n_axes = max(self.n_axes, number + 1)
            self.events += 1
        else:
            self.ignored += 1

    def button(self, number: int, pressed: bool) -> None:
        if 0 <= number < JOYSTICK_BUTTONS:
            self.buttons[number] = 1 if pressed else 0
            self.n_buttons = max(self.n_buttons, number + 1)
            self.events += 1
        else:
            self.ignored += 1

    def lost(self) -> None:
        """The device went away: centre the stick, release the buttons, mark invalid."""
        self.axes = [0.0] * JOYSTICK_AXES
        self.buttons = [0] * JOYSTICK_BUTTONS
        self.valid = False


class JsParser:
    """Splits a byte stream into js_event records and applies them to a :class:`JoystickState`."""

    record = JS_EVENT

    def __init__(self, state: JoystickState) -> None:
        self.state = state
        self._buf = b""

    def feed(self, data: bytes) -> int:
        """Apply every whole record in ``data`` (a partial one waits for more); returns records applied."""
        buf = self._buf + data
        size = self.record.size
        n = len(buf) // size
        for i in range(n):
            self.apply(*self.record.unpack_from(buf, i * size))
        self._buf = buf[n * size:]
        return n

    def apply(self, _time_ms: int, value: int, typ: int, number: int) -> None:
        kind = typ & ~JS_EVENT_INIT
        if kind == JS_EVENT_AXIS:
            self.state.axis(number, value / JS_AXIS_MAX)
        elif kind == JS_EVENT_BUTTON:
            self.state.button(number, value != 0)
        else:
            self.state.ignored += 1


class EvdevParser(JsParser):
    """Splits a byte stream into input_event records (evdev) and applies them."""

    record = INPUT_EVENT

    def __init__(self, state: JoystickState, ranges: dict[int, tuple[int, int]] | None = None,
                 default_range: tuple[int, int] = (-JS_AXIS_MAX, JS_AXIS_MAX)) -> None:
        super().__init__(state)
        self.ranges = dict(ranges or {})
        self.default_range = default_range

    def apply(self, _sec: int, _usec: int, typ: int, code: int, value: int) -> None:  # type: ignore[override]
        if typ == EV_ABS:
            if code >= JOYSTICK_AXES:
                self.state.ignored += 1
                return
            lo, hi = self.ranges.get(code, self.default_range)
            span = hi - lo
            self.state.axis(code, (2.0 * (value - lo) / span - 1.0) if span > 0 else 0.0)
        elif typ == EV_KEY:
            if BTN_JOYSTICK <= code < BTN_JOYSTICK + 16:
                self.state.button(code - BTN_JOYSTICK, value != 0)
            elif BTN_GAMEPAD <= code < BTN_GAMEPAD + 16:
                self.state.button(code - BTN_GAMEPAD, value != 0)
            else:
                self.state.ignored += 1
        elif typ != EV_SYN:
            self.state.ignored += 1


class JoystickDevice:
    """A joystick device file read without blocking; reopened after an error (see module doc)."""

    scheme = "?"

    def __init__(self, path: str, options: dict[str, str]) -> None:
        self.path = path
        self.options = options
        self.state = JoystickState()
        self.fd = -1
        self.opens = 0
        self.errors = 0
        self.last_error = ""
        self.parser = self._parser()

    def _parser(self) -> JsParser:  # pragma: no cover - interface
        raise NotImplementedError

    def _opened(self) -> None:
        """Hook after a successful open (evdev asks for the axis ranges)."""

    def open(self) -> bool:
        if self.fd >= 0:
            return True
        try:
            self.fd = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
        except OSError as exc:
            self.last_error = f"{self.path}: {exc.strerror or exc}"
            return False
        self.opens += 1
        self.parser = self._parser()
        self._opened()
        self.state.valid = True
        return True

    def close(self) -> None:
        if self.fd >= 0:
            try:
                os.close(self.fd)
            except OSError:
                pass
            self.fd = -1
        self.state.lost()

    def poll(self) -> int:
        """Read everything waiting (opening the device first if needed); returns events applied."""
        if self.fd < 0 and not self.open():
            return 0
        n = 0
        for _ in range(64):  # bounded: a device that never runs dry cannot hold the loop
            try:
                data = os.read(self.fd, READ_CHUNK_BYTES)
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno == errno.EINTR:
                    continue
                self.errors += 1
                self.last_error = f"{self.path}: {exc.strerror or exc}"
                self.close()
                break
            if not data:  # end of file: the writer went away
                self.errors += 1
                self.last_error = f"{self.path}: end of file"
                self.close()
                break
            n += self.parser.feed(data)
        return n


class JsDevice(JoystickDevice):
    """``js://PATH``: the Linux joystick API (js_event records)."""

    scheme = "js"
    OPTIONS: tuple[str, ...] = ()

    def _parser(self) -> JsParser:
        return JsParser(self.state)


class EvdevDevice(JoystickDevice):
    """``evdev://PATH[?min=LO&max=HI]``: the event interface (input_event records)."""

    scheme = "evdev"
    OPTIONS = ("min", "max")

    def _default_range(self) -> tuple[int, int]:
        try:
            lo = int(self.options.get("min", -JS_AXIS_MAX))
            hi = int(self.options.get("max", JS_AXIS_MAX))
        except ValueError:
            raise BadInput(f"joystick evdev://{self.path}: min and max must be whole numbers") from None
        if hi <= lo:
            raise BadInput(f"joystick evdev://{self.path}: max must be > min")
        return lo, hi

    def _parser(self) -> JsParser:
        return EvdevParser(self.state, {}, self._default_range())

    def _opened(self) -> None:
        ranges = {}
        for code in range(JOYSTICK_AXES):
            try:
                buf = fcntl.ioctl(self.fd, _eviocgabs(code), bytes(_ABSINFO.size))
            except OSError:
                continue  # not an evdev node (the twin's pty) or no such axis: the default range
            _v, lo, hi, *_ = _ABSINFO.unpack(buf)
            if hi > lo:
                ranges[code] = (lo, hi)
        self.parser.ranges = ranges


#: URL scheme -> driver class (the handler table; droid.brain.cell.classes names the same)
DRIVERS: dict[str, type[JoystickDevice]] = {"js": JsDevice, "evdev": EvdevDevice}


def open_joystick(url: str) -> JoystickDevice:
    """The driver for ``url`` (not yet opened: :meth:`JoystickDevice.poll` opens it).

    Bad URLs raise BadInput with the expected form."""
    form = "expected js:///dev/input/jsN or evdev:///dev/input/eventN[?min=LO&max=HI]"
    parts = urlsplit(url)
    cls = DRIVERS.get(parts.scheme)
    if cls is None or not parts.path or parts.netloc:
        raise BadInput(f"joystick device {url!r}: {form}")
    try:
        opts = dict(parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query)))
    except ValueError:
        raise BadInput(f"joystick device {url!r}: bad options; {form}") from None
    unknown = sorted(set(opts) - set(cls.OPTIONS))
    if unknown:
        allowed = ", ".join(cls.OPTIONS) or "none"
        raise BadInput(f"joystick device {url!r}: unknown option {unknown[0]!r} (allowed: {allowed})")
    return cls(parts.path, opts)
