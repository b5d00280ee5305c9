"""The joystick's twin: a Linux joystick device on a pseudo-terminal (thesis §2.6, §3.4).

Device type ``joystick`` (``[world.devices.NAME]``)::

    type = "joystick"
    device = "{run}/joy.js"     # published path; the subunit reads js://{run}/joy.js
    axes = 2                    # the thesis's Thrustmaster: 2 analog axes ...
    buttons = 8                 # ... and 8 digital inputs (§2.6)
    resync_s = 1.0              # the whole state again, as JS_EVENT_INIT records, this often [s]
    # a hand on the stick: [time s, [axis values -1..1], [buttons 0/1]] in time order
    script = [[2.0, [0.5, 0.0], [0, 0, 0, 0, 0, 0, 0, 0]], [4.0, [0.0, 0.0], [0, 0, 0, 0, 0, 0, 0, 0]]]

It writes exactly what ``/dev/input/jsN`` gives a reader: 8-byte
``struct js_event`` records (time [ms], value -32767..32767, type, number),
the initial state flagged ``JS_EVENT_INIT``, then one record per change, so
``droid-joystick`` reads it with the same driver as a real stick
(:mod:`droid.subunits.joystick.driver`).  A real device sends the initial
state when it is opened; a pty cannot tell, so the twin repeats the state
every ``resync_s``.  If nobody reads and the pty fills up, its queue is
flushed and the state written again (records stay whole).

:class:`JoystickTwin` is the core (time and a script in, js_event bytes out);
:class:`JoystickDevice` puts its bytes on the pty.  ``move(axes, buttons)``
changes the stick from a test or a lockstep run.
"""
from __future__ import annotations

import termios
from typing import Any

from droid.brain.db.layouts import JOYSTICK_AXES, JOYSTICK_BUTTONS
from droid.sim.serial_cable import PtyEnd
from droid.sim.device import Device
from droid.subunits.joystick.driver import JS_AXIS_MAX, JS_EVENT, JS_EVENT_AXIS, JS_EVENT_BUTTON, JS_EVENT_INIT


class JoystickTwin:
    """A joystick as a core: ``advance(dt_s)`` -> js_event bytes for that span of time."""

    def __init__(self, n_axes: int = 2, n_buttons: int = 8, script=(), resync_s: float = 1.0) -> None:
        if not 1 <= n_axes <= JOYSTICK_AXES or not 0 <= n_buttons <= JOYSTICK_BUTTONS:
            raise ValueError(f"joystick twin: 1..{JOYSTICK_AXES} axes and 0..{JOYSTICK_BUTTONS} buttons")
        self.n_axes = n_axes
        self.n_buttons = n_buttons
        self.axes = [0.0] * n_axes
        self.buttons = [0] * n_buttons
        self.script = sorted(script, key=lambda e: e[0])
        self.resync_s = resync_s
        self.t_s = 0.0
        self._next_resync = 0.0  # the initial state goes out on the first step
        self._pending: list[bytes] = []

    def _ms(self) -> int:
        return int(self.t_s * 1000.0) & 0xFFFFFFFF

    @staticmethod
    def _axis_value(v: float) -> int:
        return int(round(max(-1.0, min(1.0, v)) * JS_AXIS_MAX))

    def move(self, axes=None, buttons=None) -> None:
        """Set the stick (axes -1..1, buttons 0/1); a record goes out per change."""
        if axes is not None:
            for i, v in enumerate(list(axes)[: self.n_axes]):
                if self._axis_value(v) != self._axis_value(self.axes[i]):
                    self.axes[i] = float(v)
                    self._pending.append(JS_EVENT.pack(self._ms(), self._axis_value(v), JS_EVENT_AXIS, i))
        if buttons is not None:
            for i, b in enumerate(list(buttons)[: self.n_buttons]):
                b = 1 if b else 0
                if b != self.buttons[i]:
                    self.buttons[i] = b
                    self._pending.append(JS_EVENT.pack(self._ms(), b, JS_EVENT_BUTTON, i))

    def state_records(self) -> bytes:
        """The whole state as JS_EVENT_INIT records (what the kernel sends at open)."""
        ms = self._ms()
        out = [JS_EVENT.pack(ms, b, JS_EVENT_BUTTON | JS_EVENT_INIT, i) for i, b in enumerate(self.buttons)]
        out += [JS_EVENT.pack(ms, self._axis_value(v), JS_EVENT_AXIS | JS_EVENT_INIT, i)
                for i, v in enumerate(self.axes)]
        return b"".join(out)

    def advance(self, dt_s: float) -> bytes:
        self.t_s += dt_s
        while self.script and self.script[0][0] <= self.t_s:
            _, axes, buttons = self.script.pop(0)
            self.move(axes, buttons)
        out = b"".join(self._pending)
        self._pending.clear()
        if self.t_s >= self._next_resync:
            self._next_resync = self.t_s + self.resync_s
            out += self.state_records()
        return out


class JoystickDevice(Device):
    """The twin on a pty published at ``path`` (a reader opens it as js://PATH)."""
    step_s = 0.01  # its script's events and resyncs: a stick is read at 100 Hz

    def __init__(self, name: str, path: str, twin: JoystickTwin) -> None:
        self.name = name
        self.twin = twin
        self.end = PtyEnd(path)
        self.flushes = 0

    def advance(self, dt_s: float) -> None:
        data = self.twin.advance(dt_s)
        if data and self.end.write(data) != len(data):
            # nobody reads: drop the queue (stale anyway) and start again with whole records
            termios.tcflush(self.end._slave, termios.TCIFLUSH)
            self.flushes += 1
            self.end.write(self.twin.state_records())

    def close(self) -> None:
        self.end.close()


def _script(opts, n_axes: int, n_buttons: int) -> list:
    raw = opts.get("script", list, [])
    out = []
    for i, entry in enumerate(raw):
        ok = (isinstance(entry, list) and len(entry) == 3 and isinstance(entry[0], (int, float))
              and not isinstance(entry[0], bool) and entry[0] >= 0
              and isinstance(entry[1], list) and len(entry[1]) <= n_axes
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and -1 <= v <= 1 for v in entry[1])
              and isinstance(entry[2], list) and len(entry[2]) <= n_buttons
              and all(v in (0, 1) and not isinstance(v, float) for v in entry[2]))
        if not ok:
            raise opts.bad(f"script[{i}] must be [time s >= 0, [{n_axes} axes -1..1], [{n_buttons} buttons 0/1]]")
        out.append((float(entry[0]), [float(v) for v in entry[1]], [int(v) for v in entry[2]]))
    return out


def make_joystick(world, name: str, options: dict[str, Any]) -> JoystickDevice:
    """Factory for ``type = "joystick"`` (droid.sim.world.DEVICE_TYPES)."""
    path, twin = joystick_twin(world, name, options)
    return JoystickDevice(name, path, twin)


def joystick_twin(world, name: str, options: dict[str, Any]) -> tuple[str, JoystickTwin]:
    """``(device path, twin)`` of a ``joystick`` table (the pty is the caller's: lockstep has none)."""
    from droid.sim.device_options import DeviceOptions

    opts = DeviceOptions(world, name, options)
    path = opts.get("device", str)
    n_axes = opts.get("axes", int, 2, check=lambda v: None if 1 <= v <= JOYSTICK_AXES else
                      f"must be 1..{JOYSTICK_AXES}")
    n_buttons = opts.get("buttons", int, 8, check=lambda v: None if 0 <= v <= JOYSTICK_BUTTONS else
                         f"must be 0..{JOYSTICK_BUTTONS}")
    resync = opts.get("resync_s", float, 1.0, check=lambda v: None if v > 0 else "must be > 0 s")
    script = _script(opts, n_axes, n_buttons)
    opts.done()
    return path, JoystickTwin(n_axes, n_buttons, script, resync)
