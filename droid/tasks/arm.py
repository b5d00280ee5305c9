"""What the arm task programs share: the Brain's databases of one arm (thesis §3.4).

"In its essence, a Task program does the following: i) sets up shared memory
access to the required subunit databases, ii) reads these databases and iii)
modifies the command databases of the subunit to be commanded."  A task sees
the Brain's databases and the kinematics, never a device.

:class:`BrainArm` opens an arm's Status and Command records, validates targets
against the robot model *before* anything is written (so a bad target never
moves the robot), writes commands with a fresh ``cmd_id`` and ``sent = 1``,
and waits on ``busy`` / ``cmd_id`` / ``homed``.  :meth:`BrainArm.move` is a task's
positioning move -- command, wait, arrival -- that rides through a protective stop
(droid.tasks.resume: re-issued toward the same target from where the arm came to rest, at
most three times).
"""
from __future__ import annotations

import math
import sys
import time
from typing import Callable

import numpy as np

from droid.brain.cell.cellfile import Cell
from droid.brain.db import arm_command
from droid.brain.db.databases import open_brain
from droid.brain.db.layouts import CMD_OK, CMD_REFUSED, FAULT_WATCHDOG, FAULTS_CANNOT_MOVE, NORMAL_MODE, fault_names
from droid.cli import EXIT_INTERRUPTED, MAX_MOVE_S, BadInput, DroidError, RuntimeFailure
from droid.kinematics import Unreachable, load_robot
from droid.kinematics.transforms import pose_to_T
from droid.tasks import resume as rs

POLL_S = 1.0 / 120  # twice per heartbeat tick
#: How long a waiting task tolerates a stale subunit before it gives up [s].  The
#: subunit's own controller brakes on a lost link at once (docs/architecture.md);
#: this only decides when the *task* reports failure, so it rides through a
#: loaded host's scheduling gaps (seen: 0.7 s at load 18 on 2 cores).
STALE_GRACE_S = 2.0
#: A finished move must end within this of its target [joint deg] (the servo holds
#: to a few encoder counts: ~0.005 deg on the Reis) ...
ARRIVAL_TOL_DEG = 0.05
#: ... within this long after the arm reported it done [s] (the Status lags a tick
#: or two and the servo settles the last way-point).
ARRIVAL_WAIT_S = 1.0
#: A cartesian target's ZYZ angles A B C [deg] lie within one turn either way (issue 16): an angle
#: beyond names the same orientation and is refused as a mistake (1e308 deg has no precision left).
MAX_CART_ANGLE_DEG = 360.0


class Interrupted(DroidError):
    """A signal (SIGINT/SIGTERM, through the task's ``interrupted`` test) ended a move: the
    move was stopped where the arm stood (:meth:`BrainArm.give_up`).  Exit 130."""

    exit_code = EXIT_INTERRUPTED


def leg_timeout_s(seconds: float) -> float:
    """droid-move's default wait for one move of ``seconds`` [s]: 2 x its time + 10 s."""
    return 2.0 * seconds + 10.0


def say_stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class BrainArm:
    """One arm subunit as a task program sees it: the neutral arm's :class:`droid.arm.protocol.Arm`
    on shared memory (``home`` and ``move_done`` wait on the wall clock), plus the target checks,
    the waits that raise, and the positioning move that rides through a protective stop."""

    def __init__(self, cell: Cell, name: str) -> None:
        self.cell = cell
        self.faults_seen = 0  # the fault bits seen during the last wait() [FAULT_* mask]
        self.sub = cell.subunit(name)
        if not self.sub.is_arm:
            raise BadInput(f"{name} is a {self.sub.cls} subunit, not an arm")
        self.model = load_robot(self.sub.robot).with_base(pose_to_T(*self.sub.base))
        self.hb_hz = cell.heartbeat_hz
        self.status = self.command = None
        self.live_cmd: int | None = None  # our command the arm may still carry out
        self.stopped_cmd: int | None = None  # the stop written when we gave up on live_cmd

    def connect(self) -> "BrainArm":
        """Attach to the Brain's Status and Command records (RuntimeFailure if the cell is not up)."""
        self.status = open_brain(self.cell, self.sub, "status")
        try:
            self.command = open_brain(self.cell, self.sub, "command")
        except BaseException:
            self.status.close()
            raise
        return self

    def close(self) -> None:
        for db in (self.status, self.command):
            if db is not None:
                db.close()

    def __enter__(self) -> "BrainArm":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is not None and not issubclass(exc_type, BadInput):
                self.give_up()
        finally:
            self.close()

    def give_up(self) -> None:
        """The task gives up (timeout, stale, interrupted): if its command may still be
        carried out, write a stop over it (STOP_TICKS), so the arm never executes it
        later -- e.g. when a cut link comes back (no "orphan moves", issue 16)."""
        if self.live_cmd is None or self.command is None:
            return
        self.stopped_cmd = arm_command.stop(self.command)
        self.live_cmd = None

    @property
    def name(self) -> str:
        """The arm's subunit name."""
        return self.sub.name

    # -- reading ---------------------------------------------------------
    def read(self):
        return self.status.read()

    def joints_deg(self, rec=None) -> np.ndarray:
        """Current joint angles [deg] from the Status encoder positions [counts]."""
        rec = self.read() if rec is None else rec
        return self.model.gearing.counts_to_joints(np.asarray(rec["encoder_pos"], float))

    def check_fresh(self, rec=None) -> None:
        """RuntimeFailure if the arm is stale or cannot move (servo down, amplifiers latched off)."""
        rec = self.read() if rec is None else rec
        if int(rec["stale"]):
            raise RuntimeFailure(f"{self.sub.name} is stale (its agent does not answer)")
        down = int(rec["fault"]) & FAULTS_CANNOT_MOVE
        if down:
            names = ", ".join(fault_names(down))
            hint = (" (the amplifiers are latched off: the servo missed its deadlines -- a host too busy "
                    "for the cell, or sched_fifo off; power-cycle with 'droid-cell down' and 'droid-cell up')"
                    if down & FAULT_WATCHDOG else "")
            raise RuntimeFailure(f"{self.sub.name} cannot move: fault {names}{hint}")

    # -- validating (before anything moves) -------------------------------
    def ticks_for(self, seconds: float) -> int:
        if not (math.isfinite(seconds) and 0 < seconds <= MAX_MOVE_S):
            raise BadInput(f"move time must be in (0, {MAX_MOVE_S:g}] s, got {seconds!r}")
        ticks = arm_command.ticks_for(seconds, self.hb_hz)
        if ticks < 1:
            raise BadInput(f"move time {seconds:g} s is shorter than one heartbeat tick")
        return ticks

    def check_joint_target(self, counts, seconds: float, q_from_deg) -> np.ndarray:
        """Validate a joint target [counts]; returns it as int32 or raises BadInput."""
        counts = np.asarray(counts, float)
        if counts.shape != (6,) or not np.all(np.isfinite(counts)):
            raise BadInput("a joint target is 6 finite encoder counts")
        if np.any(counts != np.round(counts)):
            raise BadInput("encoder counts must be whole numbers")
        lo, hi = np.asarray(self.model.counts_min), np.asarray(self.model.counts_max)
        for i in range(6):
            if not lo[i] <= counts[i] <= hi[i]:
                raise BadInput(f"joint {i + 1} target {int(counts[i])} counts is outside "
                               f"[{int(lo[i])}, {int(hi[i])}]")
        q = self.model.gearing.counts_to_joints(counts)
        why = self.model.limit_violation(q)
        if why:
            raise BadInput(f"target outside the joint limits: {why}")
        self.check_speed(q_from_deg, q, seconds)
        return counts.astype(np.int32)

    def check_cart_target(self, pose, seconds: float, q_from_deg) -> tuple[np.ndarray, np.ndarray]:
        """Validate a cartesian target (x y z mm, A B C ZYZ deg, global frame).

        Returns (T, q_pick_deg) or raises BadInput (unreachable / out of limits / too fast)."""
        pose = np.asarray(pose, float)
        if pose.shape != (6,) or not np.all(np.isfinite(pose)):
            raise BadInput("a cartesian target is x y z [mm] A B C [ZYZ deg], all finite")
        if np.any(np.abs(pose[3:]) > MAX_CART_ANGLE_DEG):
            raise BadInput(f"the angles A B C must be within [-{MAX_CART_ANGLE_DEG:g}, {MAX_CART_ANGLE_DEG:g}] deg, "
                           f"got {' '.join(f'{a:g}' for a in pose[3:])}")
        T = pose_to_T(*pose)
        try:
            q = self.model.ik(T, np.zeros(6) if q_from_deg is None else q_from_deg)
        except Unreachable as exc:
            raise BadInput(f"target unreachable for {self.sub.name}: {exc}") from None
        self.check_speed(q_from_deg, q, seconds)
        return T, q

    def check_speed(self, q_from_deg, q_to_deg, seconds: float) -> None:
        if q_from_deg is None:  # static check only (no current position known yet)
            return
        dq = np.abs(np.asarray(q_to_deg, float) - np.asarray(q_from_deg, float))
        need = dq / seconds
        vmax = np.asarray(self.model.vmax_deg_s, float)
        for i in range(6):
            if need[i] > vmax[i] * 1.0000001:
                raise BadInput(f"too fast: joint {i + 1} would need {need[i]:.1f} deg/s "
                               f"(limit {vmax[i]:g} deg/s); allow at least "
                               f"{float(np.max(dq / vmax)):.2f} s")

    # -- commanding --------------------------------------------------------
    def _written(self, cmd_id: int) -> int:
        self.live_cmd = cmd_id
        return cmd_id

    def command_joint(self, counts, ticks: int, mode: int = NORMAL_MODE) -> int:
        """A joint command [encoder counts] in ``ticks`` heartbeat ticks (:mod:`droid.brain.db.arm_command`)."""
        return self._written(arm_command.joint(self.command, counts, ticks, mode))

    def command_cart(self, T, ticks: int) -> int:
        """A cartesian command (WCP 4x4, global, mm) in ``ticks`` heartbeat ticks."""
        return self._written(arm_command.cart(self.command, T, ticks))

    def command_jog(self, delta_counts, ticks: int = 1) -> int:
        return self._written(arm_command.jog(self.command, delta_counts, ticks))

    def command_home(self) -> int:
        return self._written(arm_command.home(self.command))

    def set_normal(self) -> None:
        """After homing the command mode becomes NORMAL (thesis §3.3); no new command."""
        arm_command.set_normal(self.command)

    # -- the Arm protocol's waits: True when the arm got there, False when not in time --------
    def home(self, timeout_s: float = 60.0) -> bool:
        """HOME, wait until homed and idle (at most ``timeout_s`` [s]), then NORMAL; False when it
        did not home in time, went stale or its homing ended otherwise (droid-home's checks that
        name the reason are :func:`droid.tasks.home.home`)."""
        cmd_id = self.command_home()
        try:
            rec = self.wait(lambda r: int(r["cmd_id"]) == cmd_id and int(r["busy"]) == 0
                            and (int(r["homed"]) or int(r["cmd_result"]) != CMD_OK), timeout_s,
                            f"{self.sub.name} to home")
        except RuntimeFailure:
            return False
        self.live_cmd = None
        if not int(rec["homed"]):
            return False
        self.set_normal()
        return True

    def move_done(self, cmd_id: int, timeout_s: float) -> bool:
        """Wait until the Status acknowledges ``cmd_id`` and is idle (at most ``timeout_s`` [s]);
        False when not in time or stale (:meth:`wait_done` raises instead and judges the result)."""
        try:
            self.wait_finished(cmd_id, timeout_s)
        except RuntimeFailure:
            return False
        return True

    # -- waiting -----------------------------------------------------------
    def wait(self, pred, timeout_s: float, what: str):
        """Poll Status until ``pred(rec)`` is true; RuntimeFailure on stale or timeout.  Keeps
        every fault bit it reads in ``faults_seen``: a failure names them though they cleared."""
        deadline = time.monotonic() + timeout_s
        stale_since = None
        self.faults_seen = 0  # every fault bit seen while waiting (check_result names them)
        while True:
            rec = self.read()
            self.faults_seen |= int(rec["fault"])
            if int(rec["stale"]):
                stale_since = stale_since or time.monotonic()
                if time.monotonic() - stale_since > STALE_GRACE_S:
                    raise RuntimeFailure(f"{self.sub.name} went stale while waiting for {what}")
            else:
                stale_since = None
                if pred(rec):
                    return rec
            if time.monotonic() > deadline:
                raise RuntimeFailure(f"timed out after {timeout_s:g} s waiting for {what}")
            time.sleep(POLL_S)

    def wait_idle(self, timeout_s: float):
        """Wait until the arm is not busy (thesis §3.4: the Move program waits on busy)."""
        return self.wait(lambda r: int(r["busy"]) == 0, timeout_s, f"{self.sub.name} to be idle")

    def wait_done(self, cmd_id: int, timeout_s: float):
        """Wait until command ``cmd_id`` finished; raises if it was refused or failed."""
        rec = self.wait_finished(cmd_id, timeout_s)
        self.check_result(rec, cmd_id)
        return rec

    def wait_finished(self, cmd_id: int, timeout_s: float, interrupted: Callable[[], bool] | None = None):
        """Wait until command ``cmd_id`` finished, done or not; its last Status record (the
        caller judges it: :meth:`check_result`).  ``interrupted()`` true meanwhile: the
        command is stopped where the arm stands (:meth:`give_up`) and :class:`Interrupted`
        raised."""
        stop = interrupted or (lambda: False)
        rec = self.wait(lambda r: stop() or (int(r["cmd_id"]) == cmd_id and int(r["busy"]) == 0),
                        timeout_s, f"{self.sub.name} to finish command {cmd_id}")
        if stop():
            self.give_up()
            raise Interrupted(f"interrupted during {self.sub.name}'s move: stopped where it stood")
        self.live_cmd = None  # finished (or refused/failed): nothing left to cancel
        return rec

    def wait_arrived(self, target_counts, timeout_s: float = ARRIVAL_WAIT_S, tol_deg: float = ARRIVAL_TOL_DEG):
        """After a move reported done: wait until every joint is within ``tol_deg`` of
        the target [counts]; RuntimeFailure naming the joint (and the faults) if the arm
        halted short of it -- e.g. the servo braked after its command stream stopped, so
        "done" is not taken for "there" (issue 16)."""
        q_goal = self.model.gearing.counts_to_joints(np.asarray(target_counts, float))
        deadline = time.monotonic() + timeout_s
        while True:
            rec = self.read()
            err = self.joints_deg(rec) - q_goal
            worst = int(np.argmax(np.abs(err)))
            if abs(err[worst]) <= tol_deg:
                return rec
            if time.monotonic() > deadline:
                faults = fault_names(rec["fault"])
                why = f" (faults: {', '.join(faults)})" if faults else ""
                pos = int(np.asarray(rec["encoder_pos"])[worst])
                raise RuntimeFailure(f"{self.sub.name} halted short of its target: joint {worst + 1} at "
                                     f"{pos} counts, {err[worst]:+.3f} deg from the target "
                                     f"{int(np.asarray(target_counts)[worst])} counts{why}")
            time.sleep(POLL_S)

    def wait_delivered(self, cmd_id: int, timeout_s: float):
        """Wait until the agent acknowledged ``cmd_id`` (Command.sent cleared)."""
        deadline = time.monotonic() + timeout_s
        while True:
            c = self.command.read()
            if int(c["cmd_id"]) != cmd_id or not int(c["sent"]):
                return
            self.check_fresh()
            if time.monotonic() > deadline:
                raise RuntimeFailure(f"command {cmd_id} not delivered to {self.sub.name} "
                                     f"within {timeout_s:g} s")
            time.sleep(POLL_S)

    def check_result(self, rec, cmd_id: int) -> None:
        """Raise if ``rec`` (the record the last :meth:`wait` returned) reports command ``cmd_id``
        refused or failed, naming the faults of ``rec`` and, when those are clear,
        ``faults_seen``: the bits seen while waiting (a servo silent for a few periods fails
        the move, then its fault bit clears; issue 16)."""
        result = int(rec["cmd_result"])
        if result == CMD_OK:
            return
        faults = fault_names(rec["fault"])
        earlier = fault_names(self.faults_seen)
        why = (f" (faults: {', '.join(faults)})" if faults
               else f" (faults while it ran, clear since: {', '.join(earlier)})" if earlier else "")
        if result == CMD_REFUSED:
            raise BadInput(f"{self.sub.name} refused command {cmd_id}{why}")
        raise RuntimeFailure(f"{self.sub.name} failed command {cmd_id}{why}")

    # -- a positioning move that rides through a protective stop (droid.tasks.resume) -------
    def move(self, mode: str, target, seconds: float, *, resume: bool = True, arrive: bool = True,
             timeout: Callable[[float], float] = leg_timeout_s, interrupted: Callable[[], bool] | None = None,
             say: Callable[[str], None] = say_stderr) -> int:
        """Move to ``target`` in ``seconds`` [s] and wait; returns how many resumes it took.

        ``mode`` "joint": ``target`` is six encoder counts [counts from home]; "cart": the wrist
        centre x y z [mm], A B C [ZYZ deg] in the global frame.  Waits until the arm is idle,
        checks the target from where it stands (BadInput: nothing moved), writes the command,
        waits until it is delivered and finished, and with ``arrive`` until the arm is within
        ARRIVAL_TOL_DEG of the target (:meth:`wait_arrived`).  ``timeout(s)`` bounds each of
        these waits of a move of ``s`` seconds (default 2 s + 10 s).

        A move a protective stop cancelled (droid.tasks.resume: it failed having seen only
        FAULT_BRAKING) is re-issued toward the same target from where the arm came to rest --
        once it is at rest with the braking fault clear, within REST_TIMEOUT_S -- at the
        original move's average joint speed, after the same target checks from there; one
        stderr line each (``say``), at most MAX_RESUMES times.  ``resume`` False
        (``--no-resume``): it fails as any failed move does.  A hard fault after the stop,
        no rest in time, or a fourth stop: RuntimeFailure naming it.  ``interrupted()`` true
        (the task's signal flag) or any exception: a command still live is stopped where the
        arm stands (:meth:`give_up`)."""
        try:
            if interrupted is not None and interrupted():
                raise Interrupted(f"interrupted before {self.sub.name}'s move")
            ticks = self.ticks_for(seconds)
            q_now = self.joints_deg(self.wait_idle(timeout(seconds)))
            cmd_id, counts, q_goal = self.write_move(mode, target, seconds, ticks, q_now)
            job = rs.Resumer(self.sub.name, q_now, q_goal, ticks / self.hb_hz, enabled=resume)
            leg_s = job.seconds
            while True:
                self.wait_delivered(cmd_id, timeout(leg_s))
                rec = self.wait_finished(cmd_id, timeout(leg_s), interrupted)
                seen = self.faults_seen
                why = job.refusal(int(rec["cmd_result"]), seen)
                if why == "":  # no protective stop (or --no-resume): done, or failed as ever
                    self.check_result(rec, cmd_id)
                    if arrive:
                        self.wait_arrived(counts)
                    return job.resumes
                if why is not None:  # the resumes are used up
                    try:
                        self.check_result(rec, cmd_id)
                    except RuntimeFailure as exc:
                        raise RuntimeFailure(f"{exc}: {why}") from None
                    raise RuntimeFailure(f"{self.sub.name} failed command {cmd_id}: {why}")
                cmd_id, counts, leg_s = self._resume(job, mode, target, seen, timeout, interrupted, say)
        except BaseException:
            self.give_up()  # a command of ours still live: stopped where the arm stands
            raise

    def write_move(self, mode: str, target, seconds: float, ticks: int, q_from_deg):
        """Check ``target`` for a move of ``seconds`` [s] from ``q_from_deg`` and write it in
        ``ticks``; (cmd_id, target [counts], target [joint deg])."""
        if mode == "joint":
            counts = self.check_joint_target(target, seconds, q_from_deg)
            return self.command_joint(counts, ticks), counts, self.model.gearing.counts_to_joints(
                np.asarray(counts, float))
        if mode != "cart":
            raise BadInput(f"a move is joint or cart, not {mode!r}")
        T, q_goal = self.check_cart_target(target, seconds, q_from_deg)
        return self.command_cart(T, ticks), self.model.gearing.joints_to_counts(q_goal), q_goal

    def _resume(self, job: "rs.Resumer", mode: str, target, seen: int, timeout, interrupted, say):
        """After a protective stop: wait until the arm rests with the braking fault clear, then
        re-issue the move from there (its line said first); (cmd_id, target [counts], its
        duration [s])."""
        rec = self._wait_rest(job, interrupted)
        q_now = self.joints_deg(rec)
        try:
            if mode == "joint":
                q_goal = self.model.gearing.counts_to_joints(np.asarray(target, float))
            else:
                _, q_goal = self.check_cart_target(target, math.inf, q_now)  # the pick from here
            seconds = job.seconds_from(q_now, q_goal, self.model.vmax_deg_s, MAX_MOVE_S)
            ticks = rs.resumed_ticks(seconds, self.hb_hz)
            check = self.check_joint_target if mode == "joint" else self.check_cart_target
            check(target, ticks / self.hb_hz, q_now)  # the same checks as the first move, from here
            say(job.next_line(q_now, seen))
            cmd_id, counts, _ = self.write_move(mode, target, ticks / self.hb_hz, ticks, q_now)
        except BadInput as exc:
            raise RuntimeFailure(f"{self.sub.name}: cannot resume after a protective stop: {exc}") from None
        return cmd_id, counts, ticks / self.hb_hz

    def _wait_rest(self, job: "rs.Resumer", interrupted):
        """The Status record that shows the arm at rest, the braking fault clear, after a
        protective stop (droid.tasks.resume.RestWatch); RuntimeFailure naming a hard fault, an
        arm not homed, or no rest within REST_TIMEOUT_S; Interrupted on ``interrupted()``."""
        watch = rs.RestWatch()
        stop = interrupted or (lambda: False)

        def rested(r) -> bool:
            if stop():
                return True
            hard = watch.hard(int(r["fault"]))
            if hard or not int(r["homed"]):
                at = round(100.0 * job.fraction(self.joints_deg(r)))
                raise RuntimeFailure(f"{self.sub.name}: protective stop at {at} % of the move, then "
                                     f"{f'fault {hard}' if hard else 'not homed'}: not resumed")
            return watch.at_rest(int(r["tick"]), r["encoder_pos"], int(r["fault"]))

        rec = self.wait(rested, rs.REST_TIMEOUT_S, f"{self.sub.name} to come to rest with its braking fault "
                                                   f"clear after a protective stop (not resumed)")
        if stop():
            raise Interrupted(f"interrupted after a protective stop of {self.sub.name}: not resumed")
        return rec
