"""droid-sim: the world behind the drivers — the hardware twins of the cell (DESIGN §1).

It hosts the simulated devices the cell file asks for and steps them on
absolute deadlines at ``[world] rate_hz``.  DROID programs never import this
package: they reach the twins only through their device drivers (a shared-memory
register map, a pseudo-terminal, ...), by the URLs in the cell file.

Each twin is a :class:`Device` with ``advance(dt_s)``; the world builds them
from the cell file (:func:`build_devices`) and steps them in order.
"""
from __future__ import annotations

import sys

from droid.brain.program import Presence, Stop, notify_ready, open_cell, parser, presence_key
from droid.brain.rt import PeriodicTimer, try_sched_fifo
from droid.cli import run

PROG = "droid-sim"
DEFAULT_RATE_HZ = 1000.0


class Device:
    """A simulated device: ``advance(dt_s)`` one world step; ``close()`` at exit."""

    name = "device"

    def advance(self, dt_s: float) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self) -> None:
        pass


def build_devices(cell) -> list[Device]:
    """The twins this cell file asks for (none are defined yet in this version)."""
    return []


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Run the simulated hardware of a cell (robots, controllers, sensors).")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    rate = float(cell.world.get("rate_hz", DEFAULT_RATE_HZ))
    Stop.install()
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    presence = Presence(cell.name, presence_key(PROG), PROG)
    devices = build_devices(cell)
    timer = PeriodicTimer(int(round(1e9 / rate)))
    try:
        presence.ready()
        notify_ready(args.ready_fd)
        dt = 1.0 / rate
        while not Stop.requested:
            n = timer.wait(0.5)
            if not n:
                continue
            for dev in devices:
                dev.advance(dt * n)
            presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns)
    finally:
        timer.close()
        for dev in devices:
            dev.close()
        presence.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
