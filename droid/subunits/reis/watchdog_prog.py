"""droid-watchdog NAME: keeps the Reis interface cards' watchdog timers alive (thesis §2.3, §4.1.4).

"A Watchdog module is executed at startup to trigger these timers
periodically. If a system failure occurs, this module would be delayed and the
timers would expire and cause a shutdown."  At 50 Hz it writes both watchdog
registers — but only while the servo is alive: it follows the servo's status
messages, and when the servo's tick stops advancing (or the servo reports a
fault) it stops kicking for good, and the hardware latches the amplifiers off
until the power is cycled (:class:`~droid.subunits.reis.watchdog.WatchdogCore`).
It reports the amplifiers' state (AMP_STATUS) as the WATCHDOG fault bit of the
controller's Status record.
"""
from __future__ import annotations

import sys

import zmq

from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import open_local
from droid.brain.runtime.program import Stop, notify_ready
from droid.brain.runtime.rt import PeriodicTimer
from droid.cli import run
from droid.subunits.reis.servo_prog import OPEN_WAIT_S, open_vme_waiting, vme_program_start
from droid.subunits.reis.station import WatchdogStation
from droid.subunits.reis.watchdog import WatchdogCore, WatchdogParams, liveness_steps

PROG = "droid-watchdog"


@run
def main(argv=None) -> int:
    args, cell, sub, ep, presence = vme_program_start(
        PROG, "Kick a Reis arm's watchdog timers while its servo is alive.", argv)
    ctx = zmq.Context()
    sub_sock = ctx.socket(zmq.SUB)
    sub_sock.setsockopt(zmq.SUBSCRIBE, b"")
    sub_sock.setsockopt(zmq.LINGER, 0)
    params = WatchdogParams(servo_liveness_steps=liveness_steps(cell.stale_ticks, cell.heartbeat_hz))
    core = WatchdogCore(params)
    bus = timer = status = None
    try:  # everything that can fail at start (no cell up: no ctrl_status) inside: the presence record is closed
        CurveHost(ctx, cell, sub.host).client(sub_sock, ep.servo_status, sub.host)
        sub_sock.connect(ep.servo_status)
        status = open_local(cell, sub, "ctrl_status")
        bus = open_vme_waiting(ep.vme, OPEN_WAIT_S)
        station = WatchdogStation(core, bus, status)
        timer = PeriodicTimer(int(round(1e9 / params.rate_hz)))
        presence.ready()
        notify_ready(args.ready_fd)
        reported = False
        while not Stop.requested:
            if not timer.wait(0.5):
                continue
            while True:
                try:
                    station.take(sub_sock.recv(zmq.NOBLOCK))
                except zmq.Again:
                    break
            station.cycle()
            if core.servo_dead and not reported:
                reported = True
                print(f"{PROG} {sub.name}: servo dead or faulted: stopped kicking; the amplifiers "
                      f"will latch off until the controller's power is cycled", file=sys.stderr, flush=True)
            presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns, bad_frames=station.bad_frames)
    finally:
        if bus is not None:
            bus.close()
        if status is not None:
            status.close()
        if timer is not None:
            timer.close()
        sub_sock.close(0)
        ctx.term()
        presence.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
