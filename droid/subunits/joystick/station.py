"""droid-joystick's cycle as one station: the device read, the reopen rule, the Status fields
(issue 25 item 3; thesis §3.4).

The real-time shell (``droid-joystick``, :mod:`droid.subunits.joystick.prog`) keeps the clock,
the Status record and the signals; :class:`JoystickStation` keeps the rules, counted in its own
cycles (never in seconds), so a lockstep runner steps the same object on virtual time:

* **a cycle** reads everything the device has waiting (:meth:`JoystickDevice.poll`) and
  returns the ``ctrl_status`` fields (``joystick_status``): axes, buttons, ``valid``, the
  event count, the DEVICE fault while the device cannot be read, ``updated_ns`` = the
  caller's clock [ns];
* **the reopen rule**: a device that went away (an error, end of file) reads as centred and
  released with ``valid = 0`` (:meth:`JoystickState.lost`), and is tried again every
  ``reopen_cycles`` cycles, not every cycle (an absent device node costs a failed open per
  try); one line says it went away, one line why it cannot be opened -- not one per try.
"""
from __future__ import annotations

import sys

from droid.brain.db.layouts import FAULT_DEVICE
from droid.subunits.joystick.driver import JoystickDevice

#: How often a device that cannot be read is tried again [s] (the shell converts to cycles).
REOPEN_S = 0.5


def record_fields(dev: JoystickDevice, now_ns: int) -> dict:
    """The ctrl_status fields of the device's state at ``now_ns`` [ns, the caller's clock]."""
    st = dev.state
    return dict(axes=st.axes, buttons=st.buttons, valid=int(st.valid), events=st.events & 0xFFFFFFFF,
                n_axes=st.n_axes, n_buttons=st.n_buttons, fault=0 if st.valid else FAULT_DEVICE,
                updated_ns=int(now_ns))


class JoystickStation:
    """droid-joystick's cycle: ``start`` once, then ``cycle`` at the subunit's ``rate_hz``.

    ``dev`` is a :class:`JoystickDevice` (the driver of ``js://`` or ``evdev://``, or any object
    with its ``poll()``, ``fd``, ``state`` and ``last_error``); ``log`` takes one line."""

    def __init__(self, dev: JoystickDevice, rate_hz: float, prog: str = "droid-joystick", log=None) -> None:
        self.dev = dev
        self.reopen_cycles = max(1, int(REOPEN_S * rate_hz))
        self.reopen_s = self.reopen_cycles / rate_hz  # [s]
        self.cycles = 0
        self.prog = prog
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))

    def start(self, now_ns: int) -> dict:
        """The first read (it opens the device); the fields to write before the program is ready."""
        self.dev.poll()
        if self.dev.fd < 0:
            self.log(f"{self.prog}: {self.dev.last_error}; retrying every {self.reopen_s:g} s")
        return record_fields(self.dev, now_ns)

    def cycle(self, now_ns: int) -> dict:
        """One cycle: read (or, every ``reopen_cycles``, try to reopen); the fields to write."""
        self.cycles += 1
        was_open = self.dev.fd >= 0
        if was_open or self.cycles % self.reopen_cycles == 0:
            self.dev.poll()
        if was_open and self.dev.fd < 0:
            self.log(f"{self.prog}: {self.dev.last_error}; reopening")
        return record_fields(self.dev, now_ns)
