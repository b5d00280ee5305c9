"""droid-joystick SUBUNIT: read a joystick device into the subunit's Status (thesis §3.4).

The joystick is a subunit of class ``joystick`` like any other (thesis §7:
"sensors such as the profiling sensor and the joystick controller could be
used on any of the two robots through the standard interface"): this program
reads the device named by the subunit's ``device`` URL
(:mod:`droid.subunits.joystick.driver`) ``rate_hz`` times a second (default
100) and writes axes, buttons and ``valid`` into its ``ctrl_status`` record;
``droid-agent`` serves that record to the Brain's ``droid-remote``, which
copies it into the Brain's Status, where ``droid-snoop`` and ``droid-jog
--joystick`` read it.  A device that cannot be read sets ``valid = 0``
(stick centred, buttons released) and the DEVICE fault, and is reopened
every ``REOPEN_S`` seconds.  The cycle and those rules are one station,
:class:`~droid.subunits.joystick.station.JoystickStation`; this shell keeps the
clock, the record and the signals.

Cell file::

    [subunits.joy]
    class = "joystick"
    host = "brain"
    device = "js://{run}/joy.js"      # or js:///dev/input/js0, evdev:///dev/input/event3
    rate_hz = 100.0
    programs = ["droid-joystick", "droid-agent"]
"""
from __future__ import annotations

import sys
import time

from droid.brain.databases import open_local
from droid.brain.registry import open_url, program
from droid.brain.program import Presence, Stop, close_all, notify_ready, presence_key, subunit_program
from droid.brain.rt import PeriodicTimer
from droid.cli import file_number, run
from droid.numbers import Range
from droid.subunits.joystick.station import JoystickStation

PROG = "droid-joystick"
DEFAULT_RATE_HZ = program(PROG).rate_hz  # [Hz], declared in droid.subunits.joystick.device
#: The read rates a joystick subunit accepts ([subunits.X] rate_hz) [Hz].
RATE_HZ = Range(1.0, 1000.0, "Hz")


def joystick_options(sub) -> tuple[str, float]:
    """(device URL, rate [Hz]) of a joystick subunit; BadInput names the key."""
    where = f"[subunits.{sub.name}]"
    sub.check_class("joystick", "a joystick")
    url = sub.device_url("a joystick", "js:///dev/input/js0")
    rate = file_number(sub.options.get("rate_hz", DEFAULT_RATE_HZ), RATE_HZ, where, "rate_hz")
    return url, rate


@run
def main(argv=None) -> int:
    args, cell, sub = subunit_program(PROG, "Read a joystick device into its subunit's Status.", argv)
    url, rate = joystick_options(sub)
    dev = open_url(url, "joystick")  # the driver droid.subunits.joystick.device declares for its scheme
    status = open_local(cell, sub, "ctrl_status")
    presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
    timer = PeriodicTimer(int(round(1e9 / rate)))
    station = JoystickStation(dev, rate, PROG)
    try:
        status.update(**station.start(time.monotonic_ns()))
        presence.ready()
        notify_ready(args.ready_fd)
        while not Stop.requested:
            if not timer.wait(0.5):
                continue
            status.update(**station.cycle(time.monotonic_ns()))
            presence.beat(0, station.cycles, timer.overruns, timer.lateness_max_ns)
    finally:
        close_all(dev, timer, status, presence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
