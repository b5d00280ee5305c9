"""droid-planner NAME: the motion controller's planner (thesis §4.1.7, figure 4.12).

"Its main purpose is to convert both cartesian and joint space move commands
into smaller joint space moves."  Per relayed heartbeat tick it reads the
controller's Command and Status records and

* does nothing before the robot is homed ("the Planner program ... suspends
  its execution until the robot has been homed"), except to hold the current
  position once homing finishes;
* on a new command (``cmd_id`` it has not planned yet) in NORMAL mode:
  JOINT — six encoder targets [counts]; CARTESIAN — x, y, z, R of the wrist
  centre in the global frame -> the 8 inverse solutions -> the pick
  (eq. 4.15) -> encoder counts (``joint_to_act``).  A target outside the
  limits or unreachable is *refused* (``cmd_result = CMD_REFUSED``) and
  nothing moves;
* every tick ``plan_joint_cmd()``: the next way-point
  ``int + (ext - int) / joint_time_count``, ``joint_time_count -= 1``,
  ``busy = joint_time_count`` (the thesis listing).  The listing keeps the move in the
  controller's Command fields; here the agent copies the Brain's Command into them every tick,
  so the planner writes its move to fields of its own (``plan_ext``, ``plan_time_count``:
  one writer a field, docs/safety.md finding 11) and reads the Brain's;
* a NORMAL command with 0 ticks (``STOP_TICKS``) is a stop: the move in
  progress ends at its current way-point and the arm holds there (a task
  that gives up writes one: issue 16);
* in JOG, HOME or OFF mode follows the arm (the next NORMAL move starts from
  where the arm is, e.g. after droid-jog);
* cancels the move and holds where the arm is if the Brain link is lost
  (``link_alive = 0``) or the servo ran out of commands and braked
  (FAULT_BRAKING): the arm stays stopped until a new command;
* the same on FAULT_FORCE (the force/torque sensor's guard on this arm, set by droid-ft
  on its host: thesis §7.3), and while it is set a new NORMAL command is refused; and the
  same on FAULT_COLLISION (the collision guard's protective stop: docs/guard.md) and on
  FAULT_GUARD (a cell that declares a guard and whose guard went silent: droid.guard.gate);
* advances its way-points by the guard's speed override (``speed``, droid.guard.gate).
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field

import numpy as np
import zmq

from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import open_local
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.runtime.rt import try_sched_fifo
from droid.brain.runtime.program import close_all, Presence, Stop, notify_ready, presence_key, subunit_program
from droid.cli import run
from droid.guard.gate import GuardGate, guard_stale_ticks
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T, record_pose
from droid.brain.db.layouts import (CMD_FAILED, CMD_OK, CMD_REFUSED, FAULT_BRAKING, FAULT_COLLISION, FAULT_FORCE,
                                 FAULT_GUARD, FAULT_SERVO, FAULT_WATCHDOG, JSPACE, NORMAL_MODE, STOP_TICKS,
                                 fault_names)
from droid.kinematics import RobotModel, Unreachable

N = 6


@dataclass
class PlanOutput:
    """What the planner writes after a tick (None = leave the field alone)."""

    encoder_cmd_int: np.ndarray | None = None  # ctrl_command, [counts]
    plan_ext: np.ndarray | None = None  # ctrl_command, [counts] (the move's resolved target)
    plan_time_count: int | None = None  # ctrl_command, ticks left
    plan_id: int | None = None  # ctrl_command
    busy: int | None = None  # ctrl_status, ticks left
    cmd_id: int | None = None  # ctrl_status
    cmd_result: int | None = None  # ctrl_status
    note: str = ""


def stop_cause(cmd, status) -> str:
    """Why the planner stops the move in progress (its log line; issue 16: a failure names
    its cause): the Brain link, the servo or watchdog faults, or the servo's braking."""
    if not int(cmd["link_alive"]):
        return "Brain link lost"
    faults = fault_names(int(status["fault"]) & (FAULT_SERVO | FAULT_WATCHDOG | FAULT_BRAKING | FAULT_FORCE
                                                  | FAULT_COLLISION | FAULT_GUARD))
    return "faults: " + ", ".join(faults)


#: the collision guard's protective stop ramps the move's speed to zero over this many heartbeat
#: ticks (250 ms at 60 Hz; docs/guard.md: the stop time in S_p includes it)
COLLISION_BRAKE_TICKS = 15


@dataclass
class PlannerCore:
    """The planner of one arm.  Pure: records in, fields out."""

    model: RobotModel  # with its base transform: commands are in the global frame
    int_counts: np.ndarray | None = None  # the current way-point [counts]; None until homed
    ext_counts: np.ndarray = field(default_factory=lambda: np.zeros(N))
    time_count: int = 0
    plan_id: int = 0
    active_id: int = 0
    refused: int = 0
    brake_step: np.ndarray | None = None  # a protective stop's ramp: the move's step when it began [counts/tick]
    speed: float = 1.0  # the collision guard's override as applied (droid.guard.gate): share of a tick's step

    def _joints_from_counts(self, counts) -> np.ndarray:
        return self.model.gearing.counts_to_joints(np.asarray(counts, float))

    def _resolve(self, cmd) -> np.ndarray:
        """The command's target in encoder counts; raises Unreachable with a reason."""
        if int(cmd["coord"]) == JSPACE:
            counts = np.asarray(cmd["encoder_cmd_ext"], float)
            why = self.model.limit_violation(self._joints_from_counts(counts))
            lo, hi = np.asarray(self.model.counts_min), np.asarray(self.model.counts_max)
            if np.any(counts < lo) or np.any(counts > hi):
                why = why or "encoder target outside the encoder limits"
            if why:
                raise Unreachable(why)
            return counts
        q = self.model.ik(record_pose(cmd), self._joints_from_counts(self.int_counts))
        return np.rint(self.model.gearing.joints_to_counts(q))

    def step(self, cmd, status) -> PlanOutput:
        """One heartbeat tick: ``cmd`` the controller Command record, ``status`` its Status."""
        out = PlanOutput()
        if not int(status["homed"]):
            self.int_counts = None
            return out
        pos = np.asarray(status["encoder_pos"], float)
        if self.int_counts is None:  # just homed: hold where the arm is
            self.int_counts = pos.copy()
            self.ext_counts = pos.copy()
            self.time_count = 0
            self.plan_id = int(cmd["cmd_id"])  # whatever was pending before homing is not replayed
            out.plan_id = self.plan_id
        if int(cmd["cmd_mode"]) != NORMAL_MODE:
            return self._follow_arm(pos, out)
        stop = self._on_faults(cmd, status, pos, out)
        new_id = int(cmd["cmd_id"])
        if not stop and new_id != self.plan_id and int(cmd["cmd_mode"]) == NORMAL_MODE:
            self._take_command(cmd, new_id, out)
        self._next_waypoint(out)
        return out

    def _follow_arm(self, pos: np.ndarray, out: PlanOutput) -> PlanOutput:
        """JOG/HOME/OFF move the arm without the planner: follow it, so that the next NORMAL
        command is planned from where the arm really is."""
        self.int_counts = pos.copy()
        self.ext_counts = pos.copy()
        self.time_count = 0
        self.brake_step = None
        out.encoder_cmd_int = np.rint(pos).astype(np.int32)
        # encoder_cmd_ext is the agent's: in JOG mode it is the Brain's RELATIVE jog [counts]
        # (§3.4) that the servo agent (droid-egm) adds once; writing the arm's absolute position
        # there once made a jog add the whole position (a runaway to the joint limits)
        out.plan_ext = out.encoder_cmd_int  # the move ends where the arm is (apply copies both into the record)
        out.plan_time_count = 0
        return out

    def _on_faults(self, cmd, status, pos: np.ndarray, out: PlanOutput) -> bool:
        """The Status faults and the link: cancel the move in progress (an over-force holds at
        its way-point; a hard stop re-anchors at the measured position), refuse or fail a new
        command that cannot move; True when no new command may start this tick."""
        dead = int(status["fault"]) & (FAULT_SERVO | FAULT_WATCHDOG)  # nothing can move
        # the F/T guard on this arm tripped (droid-ft), or the collision guard's protective stop
        collision = int(status["fault"]) & (FAULT_COLLISION | FAULT_GUARD)  # FAULT_GUARD: the guard is silent
        force = int(status["fault"]) & (FAULT_FORCE | FAULT_COLLISION | FAULT_GUARD)
        hard = not int(cmd["link_alive"]) or int(status["fault"]) & FAULT_BRAKING or dead
        if force and not hard and self.time_count > 0 and self.brake_step is None:
            if collision:
                self._brake()
            else:
                # over-force: the move ends at its current way-point and the arm holds there, as
                # on a stop command (the servo agent keeps sending that way-point): the arm stands
                # at once.  Re-anchoring at the measured position, as on a lost stream, would move
                # a pressing arm back by its following error and its drives' deflection.
                self.ext_counts = self.int_counts.copy()
                self.time_count = 0
            out.cmd_result = CMD_FAILED
            out.cmd_id = self.active_id
            out.note = f"cancelled command {self.active_id}: {stop_cause(cmd, status)}"
        if hard and (self.time_count > 0 or np.any(np.abs(self.int_counts - pos) > 0)):
            cancelled = self.time_count > 0 and self.brake_step is None
            self.brake_step = None
            self.int_counts = pos.copy()
            self.ext_counts = pos.copy()
            self.time_count = 0
            if cancelled:
                out.cmd_result = CMD_FAILED
                out.cmd_id = self.active_id
            out.note = f"cancelled command {self.active_id}: {stop_cause(cmd, status)}" if cancelled else ""
        new_id = int(cmd["cmd_id"])
        if (force and not dead and new_id != self.plan_id and int(cmd["cmd_mode"]) == NORMAL_MODE
                and int(cmd["joint_time_count"] if int(cmd["coord"]) == JSPACE else cmd["cart_time_count"])
                != STOP_TICKS):  # a stop command is still taken
            # refused, not kept waiting: the arm stands pressed until the task that armed the
            # guard disarms it (droid-contact does on exit) or droid-jog takes it away
            self.plan_id = new_id
            out.plan_id = out.cmd_id = new_id
            out.cmd_result = CMD_REFUSED
            out.note = (f"refused command {new_id}: " + ("over-force (the force/torque guard on this arm)"
                        if force & FAULT_FORCE else stop_cause(cmd, status) + " (the collision guard)"))
        if dead and new_id != self.plan_id:
            self.plan_id = new_id
            out.plan_id = out.cmd_id = new_id
            out.cmd_result = CMD_FAILED
            out.note = f"command {new_id} failed: the servo or its amplifiers are down"
        return bool(hard or force)

    def _take_command(self, cmd, new_id: int, out: PlanOutput) -> None:
        """A new NORMAL command: a stop ends the move in progress where it is; any other is
        resolved to its encoder target (or refused) and planned over its time count."""
        self.plan_id = new_id
        out.plan_id = new_id
        out.cmd_id = new_id
        ticks = int(cmd["joint_time_count"] if int(cmd["coord"]) == JSPACE else cmd["cart_time_count"])
        if ticks == STOP_TICKS:  # a stop: end the move in progress where it is and hold (issue 16)
            if self.time_count > 0:
                out.note = f"command {self.active_id} stopped by command {new_id}"
            self.ext_counts = self.int_counts.copy()
            self.time_count = 0
            self.active_id = new_id
            out.cmd_result = CMD_OK
            return
        self.brake_step = None
        try:
            target = self._resolve(cmd)
        except Unreachable as exc:
            self.refused += 1
            out.cmd_result = CMD_REFUSED
            out.note = f"refused command {new_id}: {exc}"
        else:
            self.ext_counts = target
            self.time_count = max(ticks, 1)
            self.active_id = new_id
            out.cmd_result = CMD_OK

    def _brake(self) -> None:
        """The collision guard's protective stop (docs/guard.md): the move goes on along its path
        with its speed ramping down to zero over :data:`COLLISION_BRAKE_TICKS` ticks (steps of
        n/(n+1), ..., 1/(n+1) of the move's step: n/2 steps' travel), not held at once -- a full-speed
        arm held at its way-point overruns the servo's following-error limit."""
        n = COLLISION_BRAKE_TICKS
        self.brake_step = (self.ext_counts - self.int_counts) / self.time_count
        if self.speed < 1.0:  # the step as the guard's override has it
            self.brake_step = self.brake_step * self.speed
        self.ext_counts = self.int_counts + self.brake_step * (n / 2.0)
        self.time_count = n

    def _next_waypoint(self, out: PlanOutput) -> None:
        """plan_joint_cmd(): the next interpolated way-point (thesis §4.1.7 listing); with the guard's
        override (``speed`` < 1) the way-point goes ``speed`` of the step and ``speed`` ticks pass."""
        o = self.speed
        scaled = o < 1.0 and self.brake_step is None and self.time_count > o
        if self.brake_step is not None:  # a protective stop's ramp (_brake)
            if self.time_count > 1:
                self.int_counts = self.int_counts + self.brake_step * (self.time_count / (COLLISION_BRAKE_TICKS + 1))
            else:
                self.int_counts = self.ext_counts.copy()
                self.brake_step = None
        elif scaled:
            self.int_counts = self.int_counts + (self.ext_counts - self.int_counts) * (o / self.time_count)
        elif self.time_count > 1:
            step = (self.ext_counts - self.int_counts) / self.time_count
            self.int_counts = self.int_counts + step
        else:
            self.int_counts = self.ext_counts.copy()
        if self.time_count > 0:
            self.time_count = self.time_count - o if scaled else max(self.time_count - 1, 0)
        out.encoder_cmd_int = np.rint(self.int_counts).astype(np.int32)
        out.plan_ext = np.rint(self.ext_counts).astype(np.int32)
        out.plan_time_count = out.busy = int(math.ceil(self.time_count))


def apply(out: PlanOutput, ctrl_command, ctrl_status, tick: int) -> None:
    """Write a tick's plan into the controller's records (two short locked writes)."""
    with ctrl_command.locked() as c:
        if out.encoder_cmd_int is not None:
            c["encoder_cmd_int"] = out.encoder_cmd_int
            c["plan_ext"] = out.plan_ext
            c["plan_time_count"] = out.plan_time_count
        if out.plan_id is not None:
            c["plan_id"] = out.plan_id
        c["planner_tick"] = tick
        ctrl_command.mark_written()
    fields = {k: getattr(out, k) for k in ("busy", "cmd_id", "cmd_result") if getattr(out, k) is not None}
    if fields:
        ctrl_status.update(**fields)


class PlannerStation:
    """droid-planner's cycle, once per relayed heartbeat tick: read both records, step the
    core, write the plan (:func:`apply`).  Returns the tick's :class:`PlanOutput`."""

    def __init__(self, core: PlannerCore, ctrl_command, ctrl_status, gate=None) -> None:
        self.core = core
        self.ctrl_command = ctrl_command
        self.ctrl_status = ctrl_status
        self.gate = gate  # a droid.guard.gate.GuardGate where the cell declares a guard
        self.last_cmd = None  # the Command record of the last cycle

    def cycle(self, tick: int) -> PlanOutput:
        cmd, st = self.ctrl_command.read(), self.ctrl_status.read()
        self.last_cmd = cmd  # the record this tick planned from (droid-planner's jump check)
        if self.gate is not None:  # the guard's stale rule (FAULT_GUARD) and its override
            self.core.speed = self.gate.apply(cmd, st, tick, self.ctrl_status)
        out = self.core.step(cmd, st)
        apply(out, self.ctrl_command, self.ctrl_status, tick)
        return out


PROG = "droid-planner"


class JumpCheck:
    """droid-planner's log of a way-point that steps farther in one tick than half the robot
    file's joint speed limit (``vmax_deg_s``) allows -- tracking steps a hundredth of it, the
    start moves under half -- its line naming the command it came from (id, joint or cartesian,
    its ticks, its pose or counts) beside the way-points before and after [counts]; one line a
    command.  The servo would ramp toward it at full speed (a
    following error on a fresh machine's demo, docs/safety.md finding 11); the check only logs."""

    SHARE = 0.5  # of the joint speed limit

    def __init__(self, model: RobotModel, heartbeat_hz: float) -> None:
        # each motor's counts a tick with every joint at SHARE of its limit (the coupling's too)
        self.limit = (np.abs(model.gearing.joint_to_counts_matrix) @ np.asarray(model.vmax_deg_s, float)
                      * (self.SHARE / float(heartbeat_hz)))  # [counts/tick]
        self.last: np.ndarray | None = None
        self.jumps = 0
        self.said: int | None = None  # the command of the last line

    def note(self, out: PlanOutput, cmd) -> str:
        """'' or the line for this tick's way-point (``out``), planned from the Command ``cmd``."""
        wp = out.encoder_cmd_int
        if wp is None:
            return ""
        before, self.last = self.last, wp
        if before is None:
            return ""
        step = np.abs(wp.astype(np.int64) - before)
        if not np.any(step > self.limit):
            return ""
        self.jumps += 1
        if int(cmd["cmd_id"]) == self.said:
            return ""
        self.said = int(cmd["cmd_id"])
        j = int(np.argmax(step / self.limit))
        cart = int(cmd["coord"]) != JSPACE
        what = (f"cartesian, {int(cmd['cart_time_count'])} ticks, pose x {float(cmd['x']):.2f} y {float(cmd['y']):.2f} "
                f"z {float(cmd['z']):.2f} mm R {np.round(np.asarray(cmd['R'], float), 5).tolist()}" if cart else
                f"joint, {int(cmd['joint_time_count'])} ticks, counts {np.asarray(cmd['encoder_cmd_ext']).tolist()}")
        return (f"way-point step over half the joint speed limit: joint {j + 1} {int(step[j])} counts in one tick "
                f"(limit {self.limit[j]:.0f}); command {int(cmd['cmd_id'])} ({what}); way-point "
                f"{before.tolist()} -> {wp.tolist()} (target {np.asarray(out.plan_ext).tolist()}; "
                f"{self.jumps} so far)")


@run
def main(argv=None) -> int:
    args, cell, sub = subunit_program(PROG, "Plan an arm's joint and cartesian commands into per-tick way-points (thesis §4.1.7).", argv, arm=True)
    model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    ctrl_command = open_local(cell, sub, "ctrl_command")
    ctrl_status = open_local(cell, sub, "ctrl_status")
    ctx = zmq.Context()
    ticks = TickSubscriber(ctx, sub.relay, CurveHost(ctx, cell, sub.host), sub.host)
    presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
    ticks.say = presence.say
    core = PlannerCore(model)
    stale = guard_stale_ticks(cell)  # a cell that declares a guard: its stale rule and override
    station = PlannerStation(core, ctrl_command, ctrl_status, None if stale is None else GuardGate(stale))
    jumps = JumpCheck(model, cell.heartbeat_hz)
    try:
        presence.ready()
        notify_ready(args.ready_fd)
        last = 0
        while not Stop.requested:
            t = ticks.wait(0.5)
            if t is None:
                presence.beat(last, core.refused, ticks.monitor.missed, ticks.lateness_max_ns, bad_frames=ticks.bad_frames)
                continue
            last = t.tick
            out = station.cycle(t.tick)
            if out.note:
                print(f"{PROG} {sub.name}: {out.note}", file=sys.stderr, flush=True)
            jump = jumps.note(out, station.last_cmd)
            if jump:
                print(f"{PROG} {sub.name}: {jump}", file=sys.stderr, flush=True)
            presence.beat(last, core.refused, ticks.monitor.missed, ticks.lateness_max_ns, bad_frames=ticks.bad_frames)
    finally:
        close_all(ticks, ctx.term, ctrl_command, ctrl_status, presence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
