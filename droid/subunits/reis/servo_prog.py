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

A flight record keeps the last :data:`FLIGHT_TICKS` ticks (tick, timer periods, wake-up
lateness [us], commands taken, positions and target [extended counts], DACs [DAC counts]);
a new fault prints it after the fault's line, one ``flight`` line per tick, oldest first, so
the ticks that led to a following error or an encoder jump are on the log
(docs/safety.md).
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np
import zmq

from droid import kernel
from droid.brain.plumbing.curve import CurveHost
from droid.brain.runtime.program import Presence, Stop, notify_ready, presence_key, subunit_program
from droid.brain.runtime.rt import PeriodicTimer, try_sched_fifo
from droid.cli import BadInput, RuntimeFailure, run
from droid.kinematics import RobotFileError
from droid.subunits.reis.brake_log import BrakeRecorder
from droid.subunits.reis.endpoints import reis_endpoints
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.robot_file import read_offsets
from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.station import ServoStation
from droid.brain.cell.registry import open_url
from droid.subunits.reis.device import SERVO_HZ
from droid.subunits.reis.vme import VmeOpenError

PROG = "droid-servo"
OPEN_WAIT_S = 20.0
LATENESS_WINDOW = 30000  # wake-ups kept for the exit report (60 s at 500 Hz)  # droid-sim creates the register map in parallel at cell start
FLIGHT_TICKS = 150  # the flight record's depth [servo ticks] (0.3 s at 500 Hz)
FLIGHT_COLUMNS = ("tick", "periods", "late_us", "taken") + tuple(
    f"{what}{j}" for what in ("pos", "target", "dac") for j in range(1, 7))


def open_vme_waiting(url: str, wait_s: float):
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return open_url(url, "vme")  # droid.subunits.reis.vme.open_vme, by the registry
        except VmeOpenError:
            if time.monotonic() > deadline or Stop.requested:
                raise
            time.sleep(0.05)


def vme_program_start(prog: str, description: str, argv):
    """The start the programs on a Reis arm's VME cards share (droid-servo, droid-watchdog): the
    arguments, cell and arm subunit, the arm's endpoints, SCHED_FIFO when the cell asks for it,
    and the program's presence record.  Returns ``(args, cell, sub, endpoints, presence)``."""
    args, cell, sub = subunit_program(prog, description, argv, arm=True)
    ep = reis_endpoints(cell, sub)
    try_sched_fifo(wanted=cell.sched_fifo, prog=prog)
    return args, cell, sub, ep, Presence(cell.name, presence_key(prog, sub.name), f"{prog} {sub.name}")


@run
def main(argv=None) -> int:
    args, cell, sub, ep, presence = vme_program_start(
        PROG, "Run the 500 Hz servo loop of a Reis arm on its VME interface cards.", argv)
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
    loop = None
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
        loop = _ServoLoop(sub.name, core, bus, timer, pull, pub, presence)
        loop.run()
        loop.report_lateness()
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
        presence.close(failed=loop is not None and loop.failed)
    return 0


class _ServoLoop:
    """droid-servo's 500 Hz loop (the module docstring): each period the commands that arrived,
    one ServoStation cycle (read, core, write), its status published, the halts and refusals
    logged.  Everything a period touches is made here, before the loop starts."""

    def __init__(self, name: str, core: ServoCore, bus, timer: PeriodicTimer, pull, pub, presence) -> None:
        self.name, self.core, self.bus, self.timer = name, core, bus, timer
        self.pull, self.pub, self.presence = pull, pub, presence
        self.station = ServoStation(core, bus)
        self.halts = BrakeRecorder()
        self.lateness_us = np.zeros(LATENESS_WINDOW, np.float32)  # the last minute of wake-ups
        self.n_late = 0
        self.refused_seen, self.refused_tick = 0, -SERVO_HZ - 1
        self.flight: list = [None] * FLIGHT_TICKS  # a ring, by n_late: (tick, periods, late_us, taken, sample)
        self.failed = False  # the VME access failed (the exit is a failure)

    def run(self) -> None:
        """Until SIGTERM/SIGINT, on absolute deadlines."""
        timer, core, station, presence = self.timer, self.core, self.station, self.presence
        while not Stop.requested:
            periods = timer.wait(0.5)
            if not periods:
                continue
            self.lateness_us[self.n_late % LATENESS_WINDOW] = timer.lateness_ns / 1e3
            self.n_late += 1
            arrived = self._receive()
            report = self._cycle(periods, arrived)
            if core.refused_resumes != self.refused_seen:  # at most one line per episode of refusals
                self._log_refusal()
            event = self.halts.step(core.tick, arrived, core.starved, core.encoder_pos, core.homing)
            if event is not None:
                print(f"{PROG} {self.name}: halt {json.dumps(event.as_dict())}", file=sys.stderr, flush=True)
            if report is not None:
                self.pub.send(report, zmq.NOBLOCK)
            presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns, bad_frames=station.bad_frames)

    def _receive(self) -> bool:
        """Every 60 Hz command that arrived, in order; whether one did."""
        arrived = False
        while True:
            try:
                msg = self.pull.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            arrived = self.station.take(msg) or arrived
        return arrived

    def _cycle(self, periods: int, arrived: bool):
        """One station cycle (encoders and switches in, DACs out), recorded in the flight record
        (``arrived``: a command was taken before it); its status message or None.  A new fault is
        logged with the registers re-read and the flight record; a VME error ends the program."""
        core, station = self.core, self.station
        try:
            fault_before = core.fault
            report = station.cycle(periods)
            self.flight[self.n_late % FLIGHT_TICKS] = (core.tick, periods, self.timer.lateness_ns // 1000, int(arrived),
                                                       core.flight_sample())
            if core.fault != fault_before:
                s = core.status()
                print(f"{PROG} {self.name}: fault {s.fault.name} at servo tick {s.tick}: raw encoders "
                      f"{station.raw}, positions {s.encoder_pos}, following error {s.following_error}, "
                      f"{self.timer.overruns} overruns so far; registers re-read now: "
                      f"{self.bus.read_encoders_raw()}", file=sys.stderr, flush=True)
                self._print_flight()
        except (OSError, ValueError) as exc:
            self.failed = True
            raise RuntimeFailure(f"VME access failed: {exc}") from None
        return report

    def _print_flight(self) -> None:
        """The flight record, oldest tick first: a header line, then one line per tick (this
        tick, the fault's, last)."""
        n = min(self.n_late, FLIGHT_TICKS)  # this tick's row is n_late's (run counts it first)
        first = self.n_late - n + 1
        print(f"{PROG} {self.name}: flight " + " ".join(FLIGHT_COLUMNS), file=sys.stderr)
        for i in range(first, first + n):
            *head, (pos, target, dac) = self.flight[i % FLIGHT_TICKS]
            values = head + np.frombuffer(pos, np.int64).tolist() + np.frombuffer(target, np.int64).tolist() + list(dac)
            print(f"{PROG} {self.name}: flight " + " ".join(map(str, values)), file=sys.stderr)
        sys.stderr.flush()

    def _log_refusal(self) -> None:
        """A refused way-point: one line per episode (none within a second of the last)."""
        core = self.core
        if core.tick - self.refused_tick > SERVO_HZ:
            print(f"{PROG} {self.name}: refused a way-point at servo tick {core.tick}: braked to rest "
                  f"at {core.encoder_pos} and the way-point is farther than "
                  f"{core.params.resume_window_counts} counts (a stale target; "
                  f"{core.refused_resumes} refused so far)", file=sys.stderr, flush=True)
        self.refused_seen, self.refused_tick = core.refused_resumes, core.tick

    def report_lateness(self) -> None:
        """The exit report: cycles, overruns, and the wake-up lateness of the last minute."""
        timer, n_late = self.timer, self.n_late
        if n_late:
            w = self.lateness_us[: min(n_late, LATENESS_WINDOW)]
            print(f"{PROG} {self.name}: {timer.cycles} cycles, {timer.overruns} overruns "
                  f"({100.0 * timer.overruns / max(1, timer.cycles + timer.overruns):.3f} %); wake-up "
                  f"lateness over the last {len(w)} cycles: median {np.median(w):.0f} us, p99 "
                  f"{np.percentile(w, 99):.0f} us, max {w.max():.0f} us; kernel {kernel.NAME}", file=sys.stderr,
                  flush=True)


if __name__ == "__main__":
    sys.exit(main())
