"""droid-servo NAME: the 500 Hz servo program of the Reis motion controller (thesis §4.1.5, fig. 4.7).

Each 2 ms, on absolute deadlines: apply the command messages that arrived
from the servo agent (the servo planner, §4.1.5.2), read the six encoder
counters and the limit switches through the VME driver, run the servo core
(queue/cache, braking, PID, homing: :class:`~droid.subunits.reis.servo.ServoCore`),
write the six DACs.  Every few ticks it publishes its status for the servo
agent and the watchdog.  It never takes a shared-database semaphore (§4.1.6).

On exit, and on any error in read/write (ros2_control's ``on_error``), the
DACs are zeroed.  The watchdog notices a dead servo and latches the amplifiers
off.

Every halt of the arm (the end of a move, an emergency stop) is recorded in
servo ticks (:mod:`~droid.subunits.reis.brake_log`) and printed as one line
``droid-servo NAME: halt {json}`` on the servo's log.
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np
import zmq

from droid.brain.curve import CurveHost
from droid.brain.program import Presence, Stop, notify_ready, presence_key, subunit_program
from droid.brain.rt import PeriodicTimer, try_sched_fifo
from droid.cli import BadInput, RuntimeFailure, run
from droid.kinematics import RobotFileError
from droid.subunits.reis.brake_log import BrakeRecorder
from droid.subunits.reis.endpoints import reis_endpoints
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.robot_file import read_offsets
from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.station import ServoStation
from droid.brain.registry import open_url
from droid.subunits.reis.device import SERVO_HZ
from droid.subunits.reis.vme import VmeOpenError

PROG = "droid-servo"
OPEN_WAIT_S = 20.0
LATENESS_WINDOW = 30000  # wake-ups kept for the exit report (60 s at 500 Hz)  # droid-sim creates the register map in parallel at cell start


def open_vme_waiting(url: str, wait_s: float):
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return open_url(url, "vme")  # droid.subunits.reis.vme.open_vme, by the registry
        except VmeOpenError:
            if time.monotonic() > deadline or Stop.requested:
                raise
            time.sleep(0.05)


@run
def main(argv=None) -> int:
    args, cell, sub = subunit_program(PROG, "Run the 500 Hz servo loop of a Reis arm on its VME interface cards.", argv, arm=True)
    ep = reis_endpoints(cell, sub)
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, sub.host)
    pull = ctx.socket(zmq.PULL)
    pull.setsockopt(zmq.LINGER, 0)
    pull.setsockopt(zmq.RCVHWM, 8)
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.setsockopt(zmq.SNDHWM, 4)
    bus = None
    timer = None
    failed = False
    try:
        curve.bind(cell, (pull, ep.servo), (pub, ep.servo_status))
        bus = open_vme_waiting(ep.vme, OPEN_WAIT_S)
        bus.zero_dacs()
        try:  # the arm's robot file: gains, home switches, limits; plus droid-calibrate's offsets
            core = ServoCore(ServoParams.from_robot(sub.robot, read_offsets(cell, sub.name)))
        except (RobotFileError, ValueError) as exc:
            raise BadInput(str(exc)) from None
        timer = PeriodicTimer(int(round(1e9 / SERVO_HZ)))
        presence.ready()
        notify_ready(args.ready_fd)
        station = ServoStation(core, bus)
        halts = BrakeRecorder()
        lateness_us = np.zeros(LATENESS_WINDOW, np.float32)  # the last minute of wake-ups
        n_late = 0
        refused_seen, refused_tick = 0, -SERVO_HZ - 1
        while not Stop.requested:
            periods = timer.wait(0.5)
            if not periods:
                continue
            lateness_us[n_late % LATENESS_WINDOW] = timer.lateness_ns / 1e3
            n_late += 1
            arrived = False
            while True:  # every 60 Hz command, in order
                try:
                    msg = pull.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                arrived = station.take(msg) or arrived
            try:
                fault_before = core.fault
                report = station.cycle(periods)
                if core.fault != fault_before:
                    s = core.status()
                    print(f"{PROG} {sub.name}: fault {s.fault.name} at servo tick {s.tick}: raw encoders "
                          f"{station.raw}, positions {s.encoder_pos}, following error {s.following_error}, "
                          f"{timer.overruns} overruns so far; registers re-read now: "
                          f"{bus.read_encoders_raw()}", file=sys.stderr, flush=True)
            except (OSError, ValueError) as exc:
                failed = True
                raise RuntimeFailure(f"VME access failed: {exc}") from None
            if core.refused_resumes != refused_seen:  # at most one line per episode of refusals
                if core.tick - refused_tick > SERVO_HZ:
                    print(f"{PROG} {sub.name}: refused a way-point at servo tick {core.tick}: braked to rest "
                          f"at {core.encoder_pos} and the way-point is farther than "
                          f"{core.params.resume_window_counts} counts (a stale target; "
                          f"{core.refused_resumes} refused so far)", file=sys.stderr, flush=True)
                refused_seen, refused_tick = core.refused_resumes, core.tick
            event = halts.step(core.tick, arrived, core.starved, core.encoder_pos, core.homing)
            if event is not None:
                print(f"{PROG} {sub.name}: halt {json.dumps(event.as_dict())}", file=sys.stderr, flush=True)
            if report is not None:
                pub.send(report, zmq.NOBLOCK)
            presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns, bad_frames=station.bad_frames)
        if n_late:
            w = lateness_us[: min(n_late, LATENESS_WINDOW)]
            print(f"{PROG} {sub.name}: {timer.cycles} cycles, {timer.overruns} overruns "
                  f"({100.0 * timer.overruns / max(1, timer.cycles + timer.overruns):.3f} %); wake-up "
                  f"lateness over the last {len(w)} cycles: median {np.median(w):.0f} us, p99 "
                  f"{np.percentile(w, 99):.0f} us, max {w.max():.0f} us", file=sys.stderr, flush=True)
    finally:
        if bus is not None:
            try:
                bus.zero_dacs()
            except (OSError, ValueError):
                pass
            bus.close()
        if timer is not None:
            timer.close()
        pull.close(0)
        pub.close(0)
        curve.close()
        ctx.term()
        presence.close(failed=failed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
