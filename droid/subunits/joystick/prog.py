"""droid-joystick SUBUNIT...: read a joystick device into the subunit's Status (thesis §3.4).

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

Named several subunits (a cell's ``[cell] share = ["droid-joystick"]``, issue 28 item 4), one
process reads every joystick of its host, each at its own ``rate_hz`` on a loop at the highest
of them, each with its own device, record and reopen rule.
"""
from __future__ import annotations

import sys
import time

from droid.brain.db.databases import open_local
from droid.brain.cell.registry import open_url, program
from droid.brain.runtime.program import Stop, close_all, notify_ready, serving_presence, subunit_program
from droid.brain.runtime.rt import PeriodicTimer
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
    args, cell, subs = subunit_program(PROG, "Read joystick devices into their subunits' Status.", argv,
                                       example="joy (several: one process reads them all)",
                                       several=True, one_host=True)
    opts = [joystick_options(sub) for sub in subs]
    rate = max(r for _, r in opts)  # the loop's; each joystick is read at its own rate_hz
    presence = serving_presence(cell, PROG, subs)
    timer = PeriodicTimer(int(round(1e9 / rate)))
    devs, records, stations = [], [], []
    try:
        for sub, (url, r) in zip(subs, opts):
            devs.append(open_url(url, "joystick"))  # the driver droid.subunits.joystick.device declares
            records.append(open_local(cell, sub, "ctrl_status"))
            stations.append(JoystickStation(devs[-1], r, f"{PROG} {sub.name}" if len(subs) > 1 else PROG))
        now = time.monotonic_ns()
        for status, station in zip(records, stations):
            status.update(**station.start(now))
        periods = [int(round(1e9 / r)) for _, r in opts]  # [ns]
        due = [now] * len(periods)  # [ns, monotonic]: each joystick's next cycle
        presence.ready()
        notify_ready(args.ready_fd)
        while not Stop.requested:
            if not timer.wait(0.5):
                continue
            now = time.monotonic_ns()
            for k, (status, station) in enumerate(zip(records, stations)):
                if now >= due[k] - periods[k] // 4:  # this joystick's period is up (a quarter's slack)
                    status.update(**station.cycle(now))
                    due[k] = max(due[k] + periods[k], now + periods[k] // 2)
            if presence.due():
                presence.beat(0, max(st.cycles for st in stations), timer.overruns, timer.lateness_max_ns)
    finally:
        close_all(*devs, timer, *records, presence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
