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
has re-anchored its way-point at the stopped position.  A cycle that wakes after the agent
itself was deaf (stopped, starved of CPU) while the servo ran on drains a queue of old reports
(not yet starved, the target of then): it trusts none of them and sends nothing
(:meth:`ServoAgentStation.cycle`); the servo, braked to rest, also refuses a way-point that is
not where the arm stands (``resume_window_counts``).

When the way-points stop while the arm moves (issue 16, docs/safety.md finding 1)
it never re-sends the last one: the servo would ramp to it and stop within one
period, at whatever deceleration that takes.  A period whose relayed tick came
but whose way-point is not written yet (the planner is late) is bridged by one
period of the planner's own velocity; a period with no tick at all (the Brain
or its link went silent) steps the velocity down at the servo's braking profile
(``brake_decel_counts_per_tick2``), never past the planner's move target
(``plan_ext``: the planner's own field -- ``encoder_cmd_ext`` is the Brain's last joint target,
which droid-agent copies in every tick, stale during a cartesian move: bounded by it, a late
planner's bridge sent every joint moving away from it back toward it, docs/safety.md finding 11),
and holds at rest.  So the cycle must run on the relayed
tick, not on a free-running timer of its own: two free 60 Hz clocks slip a
period now and then, and a slip would read as a pause.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np
import zmq

from droid.brain.cell.device import HEARTBEAT_HZ
from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import open_local
from droid.brain.db.layouts import CMD_FAILED, CMD_OK, FAULT_BRAKING, FAULT_SERVO, HOME_MODE, HOMED, NORMAL_MODE, OFF
from droid.brain.runtime.program import close_all, Presence, Stop, notify_ready, presence_key, subunit_program
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.runtime.rt import try_sched_fifo
from droid.cli import BadInput, run
from droid.kinematics import RobotFileError
from droid.arm.pacer import TickPacer  # droid-servo-agent's and droid-egm's (the neutral arm's)
from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis.endpoints import reis_endpoints
from droid.subunits.reis.servo_params import Fault, Mode, ServoParams

PROG = "droid-servo-agent"
COMMAND_HZ = HEARTBEAT_HZ  # it runs on the relayed heartbeat tick (droid.brain.cell.device)
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

    def __init__(self, stale_ticks: int = 3, resume_window_counts: int | None = None,
                 params: ServoParams | None = None) -> None:
        self.stale_ticks = stale_ticks
        p = params or ServoParams()
        if resume_window_counts is None:
            resume_window_counts = p.resume_window_counts
        self.resume_window = resume_window_counts
        self.servo_rate_hz = float(p.servo_rate_hz)
        # A planner way-point is never farther from the servo's target than the joint
        # can travel in two command periods; a farther one is stale (the planner has
        # not re-anchored yet after the servo braked) and is not sent.
        self.max_step = (np.asarray(p.max_speed_counts_per_tick, float) * p.servo_rate_hz / p.command_rate_hz
                         * 2.0 + resume_window_counts)
        self._max_step_list = self.max_step.tolist()  # _follow_planner's plain-float copy
        self.seq = 0
        self.jog_id: int | None = None  # last JOG cmd_id applied
        self.home_id: int | None = None
        self.periods = 0
        # Way-points that stop coming (issue 16, docs/safety.md finding 1): the last way-point
        # sent [counts], the planner's velocity [counts per planner tick], the tick it came with.
        ticks_per_period = p.servo_rate_hz / p.command_rate_hz
        self.brake_per_period = np.asarray(p.brake_decel_counts_per_tick2, float) * ticks_per_period ** 2
        self._wp: np.ndarray | None = None  # the last way-point sent
        self._v = np.zeros(6)
        self._plan: np.ndarray | None = None  # the planner's last way-point
        self._wp_tick: int | None = None  # ... and its tick
        self._missed = 0  # periods in a row without a new way-point
        self._ahead = np.zeros(6)  # per joint: the direction the arm braked in, until the planner passes

    def forget_motion(self) -> None:
        """Drop what the core knows of the motion in progress (the last way-point, the planner's
        velocity, the braking direction): the next way-point is judged from scratch."""
        self._wp, self._v, self._plan, self._wp_tick, self._missed = None, np.zeros(6), None, None, 0
        self._ahead = np.zeros(6)

    def _next_without_way_point(self, ext, ticked: bool) -> np.ndarray | None:
        """The way-point [counts] of a period without a new one from the planner: the
        planner's velocity for one period if the tick came (``ticked``: the planner is
        late) and the period before had its way-point, else that velocity less the braking
        profile's deceleration (the ticks or the planner stopped).  Never past the move's
        target ``ext`` [counts].  None when at rest."""
        self._missed += 1
        if self._wp is None or not self._v.any():  # ndarray.any: np.any without its wrapper
            return None
        bridge = ticked and self._missed == 1
        speed = np.abs(self._v) if bridge else np.maximum(np.abs(self._v) - self.brake_per_period, 0.0)
        if not bridge:
            self._ahead = np.where(self._v != 0, np.sign(self._v), self._ahead)
        v = np.sign(self._v) * speed
        nxt = self._wp + v
        ext = np.asarray(ext, float)
        past = np.sign(v) * (nxt - ext) > 0  # would pass the target: stop on it
        nxt[past] = ext[past]
        self._v = np.where(past, 0.0, v)
        self._wp = nxt
        return nxt

    def _send(self, mode: Mode, counts, status, faults, why: str = "") -> AgentDecision:
        self.seq += 1
        vals = counts.tolist() if isinstance(counts, np.ndarray) else counts  # plain floats round faster
        return AgentDecision(sw.ServoCommand(self.seq, int(mode), tuple([int(round(v)) for v in vals])),
                             status, faults, why)

    def step(self, cmd, report: sw.ServoReport | None, report_fresh: bool, ticked: bool = True) -> AgentDecision:
        """One period.  ``ticked``: a relayed heartbeat tick came since the last period
        (False: the Brain or its link is silent, so a missing way-point is a real pause)."""
        status: dict = {}
        self.periods += 1
        faults = self._read_report(report, report_fresh, status)
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
            return self._link_lost(cmd, mode, report, status, faults)
        try:
            servo_mode = Mode(mode)  # the servo message carries cmd_mode's own numbers
        except ValueError:
            return AgentDecision(None, status, faults, f"unknown command mode {mode}")
        counts = (0,) * 6
        if servo_mode != Mode.NORMAL or not report.homed:
            self.forget_motion()
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
                return self._follow_planner(cmd, report, status, faults, ticked)
        return self._send(servo_mode, counts, status, faults)

    def _read_report(self, report: sw.ServoReport | None, report_fresh: bool, status: dict) -> int:
        """The servo's report into ``status`` (encoders, homed); its fault bits (FAULT_BRAKING when
        it starved, FAULT_SERVO on a fault or a silence after the start-up grace)."""
        faults = 0
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
        return faults

    def _link_lost(self, cmd, mode: int, report: sw.ServoReport, status: dict, faults: int) -> AgentDecision:
        """The way-points stopped with the link: finish the stop through the braking profile
        (bounded by the move's target), then fall silent (the servo holds)."""
        nxt = (self._next_without_way_point(cmd["plan_ext"], False)
               if mode == NORMAL_MODE and report.homed else None)
        if nxt is not None:
            return self._send(Mode.NORMAL, nxt, status, faults, "Brain link lost: braking")
        self.forget_motion()
        return AgentDecision(None, status, faults, "Brain link lost")

    def _follow_planner(self, cmd, report: sw.ServoReport, status: dict, faults: int,
                        ticked: bool) -> AgentDecision:
        """NORMAL mode on a homed arm: the planner's new way-point, checked against the servo's
        target; without one, bridge a late planner or brake (_next_without_way_point)."""
        brain_tick, planner_tick = int(cmd["brain_tick"]), int(cmd["planner_tick"])
        silent = brain_tick - planner_tick > self.stale_ticks
        if silent or planner_tick == self._wp_tick:
            # no new way-point this period: never the same one again (the servo would
            # stop within one period); bridge a late planner, brake if the ticks stopped
            nxt = self._next_without_way_point(cmd["plan_ext"], ticked and not silent)
            if nxt is not None:
                return self._send(Mode.NORMAL, nxt, status, faults,
                                  "planner silent: braking" if silent else "")
            if silent:
                self.forget_motion()
                return AgentDecision(None, status, faults, "planner silent")
            if self._wp is not None:  # at rest where the braking ended: hold there
                return self._send(Mode.NORMAL, self._wp, status, faults)
        target = np.asarray(cmd["encoder_cmd_int"], np.int64)
        tl = target.tolist()  # the checks in plain ints (exact, as int64's; cheaper at six values)
        rw = self.resume_window
        if report.starved and any(abs(t - p) > rw for t, p in zip(tl, report.encoder_pos)):
            self.forget_motion()
            return AgentDecision(None, status, faults, "waiting for the planner to re-anchor")
        if any(abs(t - c) > m for t, c, m in zip(tl, report.encoder_cmd, self._max_step_list)):
            faults |= FAULT_BRAKING  # tells the planner to re-anchor where the arm is
            self.forget_motion()
            return AgentDecision(None, status, faults, "way-point too far from the servo's target")
        if self._plan is not None and self._wp_tick is not None and planner_tick > self._wp_tick:
            self._v = (target - self._plan) / (planner_tick - self._wp_tick)
        send = target.astype(float)
        if self._ahead.any():
            # the ticks came back after the arm braked ahead of the planner's way-points:
            # a joint the planner still drives the same way waits for them to pass it
            # (it does not back up); a joint the planner turned is released
            wait = (self._ahead * (send - self._wp) < 0) & (self._ahead * self._v > 0)
            send[wait] = self._wp[wait]
            self._ahead[~wait] = 0.0
        self._wp, self._plan = send, target.astype(float)
        self._wp_tick, self._missed = planner_tick, 0
        counts = tuple([round(v) for v in send.tolist()])  # half to even, as round(np.float64)
        return self._send(Mode.NORMAL, counts, status, faults)


class ServoAgentStation:
    """droid-servo-agent's cycle: ``take`` each servo status message, ``cycle`` at 60 Hz.

    A status is *fresh* for the core's ``stale_ticks`` command periods after it arrived (the
    cell file's ``stale_ticks``: one silence rule for every link); the cycle reads the
    Command record, steps :class:`ServoAgentCore` and writes its status fields and its own
    fault bits (``MY_FAULTS``; FAULT_WATCHDOG is droid-watchdog's) into the Status record
    under one lock.  It returns the command message to send, or None (the servo brakes).
    Time ``now_ns`` is the caller's clock [ns]: CLOCK_MONOTONIC, or lockstep's virtual time.
    """

    def __init__(self, core: ServoAgentCore, ctrl_command, ctrl_status, command_hz: float = COMMAND_HZ) -> None:
        self.core = core
        self.ctrl_command = ctrl_command
        self.ctrl_status = ctrl_status
        self.fresh_ns = int(core.stale_ticks * 1e9 / command_hz)  # [ns]
        # the servo ticks one stale window holds: more between two cycles' newest reports and
        # the agent was deaf while the servo ran (stopped, starved of CPU), so what it drained
        # may be a queue of old reports and the newest of them old too
        self.catch_up_ticks = core.stale_ticks * core.servo_rate_hz / command_hz
        self.report: sw.ServoReport | None = None
        self.report_ns = 0
        self._cycle_tick: int | None = None  # the servo tick of the newest report at the last cycle
        self.catch_ups = 0  # cycles that distrusted a drained queue
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

    def cycle(self, now_ns: int, late_ns: int = 0, ticked: bool = True) -> bytes | None:
        """One 60 Hz period.  ``late_ns``: how late this cycle itself runs [ns] (a stalled
        host): the servo's silence is judged only over time the agent was awake to hear it,
        so a stall of the whole host is not taken for a dead servo (issue 16; the servo
        judges the stall itself: its queue runs dry and it brakes).  ``ticked``: a relayed
        heartbeat tick came since the last cycle (see :meth:`ServoAgentCore.step`)."""
        fresh = self.report is not None and now_ns - self.report_ns < self.fresh_ns + max(0, late_ns)
        catching_up = False
        if self.report is not None:
            tick, before = self.report.tick, self._cycle_tick
            self._cycle_tick = tick
            if fresh and before is not None and tick - before > self.catch_up_ticks:
                # the servo ran on while this agent did not hear it: the reports just drained
                # may be a queue from before the gap (not yet starved, the target of then),
                # so this period commands nothing; the servo has braked anyway, since its
                # cache ran dry during the gap.  The next cycle reads the live reports.
                # (A stall of the whole host stops the servo too: its tick barely moves.)
                catching_up = True
                self.catch_ups += 1
        if catching_up:  # FAULT_BRAKING: the planner cancels the move and re-anchors
            self.core.forget_motion()
            d = self.last = AgentDecision(None, {}, FAULT_BRAKING, "catching up on the servo's status "
                                          f"({tick - before} servo ticks since the last cycle)")
        else:
            d = self.last = self.core.step(self.ctrl_command.read(), self.report, fresh, ticked)
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
    if abs(cell.heartbeat_hz - COMMAND_HZ) > 1e-9:
        raise BadInput(f"{PROG}: the Reis servo takes one way-point per {COMMAND_HZ:g} Hz period; "
                       f"this cell's heartbeat_hz is {cell.heartbeat_hz:g}")
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
    ticks = TickSubscriber(ctx, sub.relay, curve, sub.host)
    pacer = TickPacer(int(round(1e9 / COMMAND_HZ)))
    station = ServoAgentStation(core, ctrl_command, ctrl_status)
    try:
        presence.ready()
        notify_ready(args.ready_fd)
        last_why = ""
        while not Stop.requested:
            t = ticks.wait(pacer.wait_s(time.monotonic_ns()))
            if t is not None:  # the planner cycles on the same tick: let it write first
                pacer.await_planner(ctrl_command, t.tick)
            now = time.monotonic_ns()
            if t is None and not pacer.due(now):
                continue
            while True:
                try:
                    station.take(sub_sock.recv(zmq.NOBLOCK), time.monotonic_ns())
                except zmq.Again:
                    break
            msg = station.cycle(now, late_ns=pacer.late_ns(now), ticked=t is not None)
            pacer.cycled(now, t is not None)
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
            presence.beat(t.tick if t is not None else 0, pacer.cycles, pacer.untimed, pacer.late_max_ns,
                          bad_frames=station.bad_frames + ticks.bad_frames)
    finally:
        close_all(ticks, push, sub_sock, ctx.term, ctrl_command, ctrl_status, presence)  # sockets: LINGER 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
