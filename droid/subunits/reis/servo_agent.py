"""droid-servo-agent NAME: the servo's proxy to the shared databases (thesis §4.1.6, figure 4.11).

"An equal priority servo agent is executed which copies pertinent data from
the shared memory on the servo function's behalf and delivers it at a fixed
rate of 60Hz to the Servo program in the form of a command message."  It also
copies the servo's status (encoder positions and commands, homed, faults)
back into the controller's Status record.

What it sends each period (:class:`ServoAgentCore`), by the Command record's
``cmd_mode`` (thesis §3.3):

* HOME — ``HOME`` (the servo starts homing on the change into HOME);
* JOG — a new command's relative encoder counts once, then zero deltas
  (works before homing: droid-jog);
* NORMAL — the planner's way-point ``encoder_cmd_int`` (home-relative);
* OFF — ``OFF`` (amplifier outputs zero).

It sends *nothing* — so the servo's cache empties and it brakes to a stop —
when the Brain link is dead (``link_alive = 0``), when the planner stopped
refreshing its way-point (``planner_tick`` more than ``stale_ticks`` behind
the relayed ``brain_tick``), or, after the servo braked, until the planner
has re-anchored its way-point at the stopped position.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np
import zmq

from droid.brain.curve import CurveHost
from droid.brain.databases import open_local
from droid.brain.layouts import CMD_FAILED, CMD_OK, FAULT_BRAKING, FAULT_SERVO, HOME_MODE, HOMED, OFF
from droid.brain.program import close_all, Presence, Stop, notify_ready, presence_key, subunit_program
from droid.brain.rt import PeriodicTimer, try_sched_fifo
from droid.cli import BadInput, run
from droid.kinematics import RobotFileError
from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis.endpoints import reis_endpoints
from droid.subunits.reis.servo_params import Fault, Mode, ServoParams

PROG = "droid-servo-agent"
COMMAND_HZ = 60.0
STARTUP_GRACE_PERIODS = 120  # 2 s for the servo's first status message
MY_FAULTS = FAULT_BRAKING | FAULT_SERVO  # FAULT_WATCHDOG is droid-watchdog's


@dataclass
class AgentDecision:
    message: sw.ServoCommand | None  # None = send nothing (the servo brakes)
    status: dict  # fields for the controller's Status record
    fault_bits: int  # this agent's fault bits (FAULT_BRAKING, FAULT_SERVO)
    why: str = ""


class ServoAgentCore:
    """Decides the servo's command for one 60 Hz period.  Pure."""

    def __init__(self, stale_ticks: int = 3, resume_window_counts: int = 20,
                 params: ServoParams | None = None) -> None:
        self.stale_ticks = stale_ticks
        self.resume_window = resume_window_counts
        p = params or ServoParams()
        # A planner way-point is never farther from the servo's target than the joint
        # can travel in two command periods; a farther one is stale (the planner has
        # not re-anchored yet after the servo braked) and is not sent.
        self.max_step = (np.asarray(p.max_speed_counts_per_tick, float) * p.servo_rate_hz / p.command_rate_hz
                         * 2.0 + resume_window_counts)
        self.seq = 0
        self.jog_id: int | None = None  # last JOG cmd_id applied
        self.home_id: int | None = None
        self.periods = 0

    def step(self, cmd, report: sw.ServoReport | None, report_fresh: bool) -> AgentDecision:
        status: dict = {}
        faults = 0
        self.periods += 1
        if report is not None:
            status.update(encoder_pos=np.asarray(report.encoder_pos, np.int32),
                          encoder_cmd=np.asarray(report.encoder_cmd, np.int32),
                          homed=HOMED if report.homed else 0)
            if report.starved:
                faults |= FAULT_BRAKING
            if report.fault:
                faults |= FAULT_SERVO
        if not report_fresh and (report is not None or self.periods > STARTUP_GRACE_PERIODS):
            faults |= FAULT_SERVO  # silent (a servo still starting up gets a grace period)
        mode = int(cmd["cmd_mode"])
        cmd_id = int(cmd["cmd_id"])
        status["cmd_mode"] = mode
        status["coord"] = int(cmd["coord"])
        if self.jog_id is None:  # commands issued before we started are not replayed
            self.jog_id = cmd_id
        if report is None or not report_fresh:
            return AgentDecision(None, status, faults, "servo silent")
        if report.fault and mode != OFF:
            if self.home_id is not None and int(cmd["cmd_mode"]) == HOME_MODE:
                status.update(cmd_result=CMD_FAILED, busy=0)
            return AgentDecision(None, status, faults, f"servo fault {Fault(report.fault).name} "
                                                        f"(command OFF to clear)")
        if not int(cmd["link_alive"]):
            return AgentDecision(None, status, faults, "Brain link lost")
        try:
            servo_mode = Mode(mode)  # the servo message carries cmd_mode's own numbers
        except ValueError:
            return AgentDecision(None, status, faults, f"unknown command mode {mode}")
        counts = (0,) * 6
        if servo_mode == Mode.HOME:
            if self.home_id != cmd_id:
                self.home_id = cmd_id
                status.update(cmd_id=cmd_id, cmd_result=CMD_OK, busy=1)
            elif report.fault == Fault.HOME_SWITCH_NOT_FOUND:
                status.update(cmd_result=CMD_FAILED, busy=0)
            else:
                status["busy"] = 0 if (report.homed and report.homing_joint < 0) else 1
        elif servo_mode == Mode.JOG:
            if cmd_id != self.jog_id:
                self.jog_id = cmd_id
                counts = tuple(int(v) for v in cmd["encoder_cmd_ext"])
                status.update(cmd_id=cmd_id, cmd_result=CMD_OK, busy=0)
        elif servo_mode == Mode.NORMAL:
            if not report.homed:
                servo_mode = Mode.JOG  # hold where it is until homed
            else:
                brain_tick, planner_tick = int(cmd["brain_tick"]), int(cmd["planner_tick"])
                if brain_tick - planner_tick > self.stale_ticks:
                    return AgentDecision(None, status, faults, "planner silent")
                target = np.asarray(cmd["encoder_cmd_int"], np.int64)
                if report.starved and np.any(np.abs(target - np.asarray(report.encoder_pos)) > self.resume_window):
                    return AgentDecision(None, status, faults, "waiting for the planner to re-anchor")
                if np.any(np.abs(target - np.asarray(report.encoder_cmd)) > self.max_step):
                    faults |= FAULT_BRAKING  # tells the planner to re-anchor where the arm is
                    return AgentDecision(None, status, faults, "way-point too far from the servo's target")
                counts = tuple(int(v) for v in target)
        self.seq += 1
        return AgentDecision(sw.ServoCommand(self.seq, int(servo_mode), counts), status, faults)


class ServoAgentStation:
    """droid-servo-agent's cycle: ``take`` each servo status message, ``cycle`` at 60 Hz.

    A status is *fresh* for three command periods after it arrived; the cycle reads the
    Command record, steps :class:`ServoAgentCore` and writes its status fields and its own
    fault bits (``MY_FAULTS``; FAULT_WATCHDOG is droid-watchdog's) into the Status record
    under one lock.  It returns the command message to send, or None (the servo brakes).
    Time ``now_ns`` is the caller's clock [ns]: CLOCK_MONOTONIC, or lockstep's virtual time.
    """

    def __init__(self, core: ServoAgentCore, ctrl_command, ctrl_status, command_hz: float = COMMAND_HZ) -> None:
        self.core = core
        self.ctrl_command = ctrl_command
        self.ctrl_status = ctrl_status
        self.fresh_ns = int(3 * 1e9 / command_hz)  # [ns]
        self.report: sw.ServoReport | None = None
        self.report_ns = 0
        self.bad_frames = 0
        self.last: AgentDecision | None = None

    def take(self, msg: bytes, now_ns: int) -> None:
        """One status message of the servo, arrived at ``now_ns`` (malformed: counted, dropped)."""
        try:
            self.report = sw.unpack_status(msg)
        except sw.BadServoMessage:
            self.bad_frames += 1
            return
        self.report_ns = now_ns

    def cycle(self, now_ns: int, late_ns: int = 0) -> bytes | None:
        """One 60 Hz period.  ``late_ns``: how late this cycle itself runs [ns] (a stalled
        host): the servo's silence is judged only over time the agent was awake to hear it,
        so a stall of the whole host is not taken for a dead servo (issue 16; the servo
        judges the stall itself: its queue runs dry and it brakes)."""
        fresh = self.report is not None and now_ns - self.report_ns < self.fresh_ns + max(0, late_ns)
        d = self.last = self.core.step(self.ctrl_command.read(), self.report, fresh)
        with self.ctrl_status.locked() as st:
            for k, v in d.status.items():
                st[k] = v
            st["fault"] = (int(st["fault"]) & ~MY_FAULTS) | d.fault_bits
            self.ctrl_status.mark_written()
        return sw.pack_command(d.message) if d.message is not None else None


@run
def main(argv=None) -> int:
    args, cell, sub = subunit_program(PROG, "Relay an arm's controller database to its servo at 60 Hz, and the servo's status back.", argv, arm=True)
    ep = reis_endpoints(cell, sub)
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    ctrl_command = open_local(cell, sub, "ctrl_command")
    ctrl_status = open_local(cell, sub, "ctrl_status")
    presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, sub.host)  # the servo runs on the same host
    push = ctx.socket(zmq.PUSH)
    for opt, val in ((zmq.LINGER, 0), (zmq.SNDHWM, 2), (zmq.IMMEDIATE, 1)):
        push.setsockopt(opt, val)
    curve.client(push, ep.servo, sub.host)
    push.connect(ep.servo)
    sub_sock = ctx.socket(zmq.SUB)
    sub_sock.setsockopt(zmq.SUBSCRIBE, b"")
    sub_sock.setsockopt(zmq.LINGER, 0)
    curve.client(sub_sock, ep.servo_status, sub.host)
    sub_sock.connect(ep.servo_status)
    try:
        core = ServoAgentCore(cell.stale_ticks, params=ServoParams.from_robot(sub.robot))
    except RobotFileError as exc:
        raise BadInput(str(exc)) from None
    timer = PeriodicTimer(int(round(1e9 / COMMAND_HZ)))
    station = ServoAgentStation(core, ctrl_command, ctrl_status)
    try:
        presence.ready()
        notify_ready(args.ready_fd)
        last_why = ""
        while not Stop.requested:
            n = timer.wait(0.5)
            if not n:
                continue
            while True:
                try:
                    station.take(sub_sock.recv(zmq.NOBLOCK), time.monotonic_ns())
                except zmq.Again:
                    break
            now = time.monotonic_ns()
            msg = station.cycle(now, late_ns=now - (timer.deadline_ns - (n - 1) * timer.period_ns))
            if msg is not None:
                try:
                    push.send(msg, zmq.NOBLOCK)
                except zmq.Again:
                    pass
            why = station.last.why
            if why != last_why:
                if why:
                    print(f"{PROG} {sub.name}: not commanding the servo: {why}", file=sys.stderr, flush=True)
                last_why = why
            presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns, bad_frames=station.bad_frames)
    finally:
        close_all(timer, push, sub_sock, ctx.term, ctrl_command, ctrl_status, presence)  # sockets: LINGER 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
