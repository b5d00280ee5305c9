"""The Fanuc S400 controller running the KAREL serial server (thesis §2.4, §4.2.1, §4.2.4) — a core.

Thesis: "a highly optimized KAREL server which receives command data via the
serial interface and translates the data into cartesian move commands"; its
68000 runs the interpreted KAREL program at no more than 6 Hz; the line is
RS-232 at 9600 baud.  This core is that controller as a pure object: bytes in
at a time, bytes out at a time, joint angles at a time; no I/O, no clock.

* The line (:class:`~droid.sim.serial_cable.PacedLine`, both ways): request
  bytes arrive at 9600 baud however fast the host wrote them; replies leave at
  9600 baud.
* The interpreter: a request line is read when its terminator arrives.  Each
  line read costs one interpreter cycle (``1 / cycle_hz`` s); a line arriving
  while the cycle of the previous one is still running is rejected with
  ``BUSY id`` (the front end reads nothing more than the id).  A motion
  request (MOVE/JMOVE/HOME) while a motion is in progress is rejected with
  ``BUSY id`` too.  The reply is queued ``reply_delay_s`` after the line ended.
* Motion: MOVE is solved with the robot model's inverse kinematics and the
  planner's pick (the solution nearest the current joints, eq. 4.15); JMOVE is
  joint angles; HOME is the joint-zero pose.  Each is one joint-interpolated
  move with a trapezoidal speed profile: all joints start and stop together,
  no joint faster than ``joint_speed_fraction`` of its velocity limit, the
  wrist centre no faster than ``speed_mm_s`` on the straight line between the
  two poses, ramps of ``ramp_s``; a requested duration ``t`` only makes it
  slower.  ``ACK id seconds`` gives the planned duration; ``DONE id`` follows
  when the move ends.
* Poses are in the robot's BASE frame (the model without a base transform).
* The arm (``KarelParams.dynamics``): False -- an ideal arm on the
  interpolated path (``q_deg`` is the trajectory); True -- the arm of the
  robot file's ``[dynamics]`` and ``[axis_servo]`` follows the path through
  the controller's joint loops (:class:`droid.arm.arm_dynamics.ArmDynamics`:
  gravity, inertia, friction, amplifier limits, reducer compliance), lagging
  it by v / kp and settling after DONE; ``q_deg`` is then the true link
  angles, ``q_motor_deg`` what the encoders count, ``q_cmd_deg`` the path.
  DONE then waits for the in-position check (every motor within
  ``inpos_deg`` of the path's end, as a controller's "fine" termination
  does), and the controller counts as moving until then.

The controller is always calibrated (its own joint angles are absolute); DROID's
notion of "homed" is about the encoder cards (droid-gmf1-encoder).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from droid.kinematics import RobotModel, Unreachable
from droid.kinematics.transforms import pose_to_T
from droid.subunits.gmf1 import karel_wire as kw
from droid.sim.serial_cable import PacedLine

_TERM = re.compile(rb"[\r\n]")


@dataclass(frozen=True)
class KarelParams:
    """Timing and motion parameters of the simulated controller (all ASSUMED: the thesis gives only 6 Hz and 9600 baud)."""

    baud: int = kw.BAUD
    cycle_hz: float = 6.0  # thesis §4.2.4: "limits the cycle rate of the KAREL Serial program to 6Hz"
    reply_delay_s: float = 0.03  # line read -> reply queued (parse, MOVE statement)
    speed_mm_s: float = 300.0  # cap on the wrist centre's straight-line speed
    joint_speed_fraction: float = 0.5  # of the robot model's vmax_deg_s
    ramp_s: float = 0.3  # acceleration and deceleration time of the trapezoid
    line_capacity_bytes: int = 4096  # bytes the host may have in flight (its tty buffer)
    dynamics: bool = False  # the arm of the robot file's [dynamics]/[axis_servo] follows the path (else ideal)
    inpos_deg: float = 1e-4  # with dynamics: DONE once the path has ended and every motor is this close [deg]

    def __post_init__(self) -> None:
        for name in ("baud", "cycle_hz", "speed_mm_s", "joint_speed_fraction", "ramp_s",
                     "line_capacity_bytes", "inpos_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"karel: {name} must be a finite number > 0, got {v!r}")
        if not (math.isfinite(self.reply_delay_s) and 0 <= self.reply_delay_s < 1.0 / self.cycle_hz):
            raise ValueError("karel: reply_delay_s must be in [0, 1 / cycle_hz)")
        if self.joint_speed_fraction > 1:
            raise ValueError("karel: joint_speed_fraction must be <= 1")


class Motion:
    """One joint-interpolated move with a trapezoidal profile (times in s, angles in deg)."""

    __slots__ = ("q0", "dq", "q1", "t0", "duration", "ta", "vp", "acc", "motion_id")

    def __init__(self, q0, q1, t0_s: float, duration_s: float, ramp_s: float, motion_id: int) -> None:
        self.q0 = np.asarray(q0, float).copy()
        self.q1 = np.asarray(q1, float).copy()
        self.dq = self.q1 - self.q0
        self.t0 = t0_s
        self.duration = max(0.0, duration_s)
        self.ta = min(ramp_s, self.duration / 2)
        self.vp = 1.0 / (self.duration - self.ta) if self.duration > 0 else 0.0
        self.acc = self.vp / self.ta if self.ta > 0 else 0.0
        self.motion_id = motion_id

    @property
    def t_end(self) -> float:
        return self.t0 + self.duration

    def fraction(self, t_s: float) -> float:
        """Normalised progress s(t) in [0, 1]."""
        tau = t_s - self.t0
        if tau <= 0:
            return 0.0
        T, ta = self.duration, self.ta
        if tau >= T:
            return 1.0
        if tau < ta:
            return 0.5 * self.acc * tau * tau
        if tau <= T - ta:
            return 0.5 * self.acc * ta * ta + self.vp * (tau - ta)
        r = T - tau
        return 1.0 - 0.5 * self.acc * r * r

    def q_at(self, t_s: float) -> np.ndarray:
        if t_s >= self.t_end:
            return self.q1
        return self.q0 + self.dq * self.fraction(t_s)

    def rate(self, t_s: float) -> float:
        """ds/dt at ``t_s`` [1/s]."""
        tau, T, ta = t_s - self.t0, self.duration, self.ta
        if tau <= 0 or tau >= T:
            return 0.0
        if tau < ta:
            return self.acc * tau
        if tau <= T - ta:
            return self.vp
        return self.acc * (T - tau)


class Halting(Motion):
    """A motion halted at ``t_s`` (KAREL ``HALT``, issue 41): on along its path, decelerating at the
    motion's own ramp, to rest (the path's progress s(t) = s0 + v0 tau - acc tau^2 / 2)."""

    def __init__(self, m: Motion, t_s: float) -> None:  # noqa: super().__init__ not wanted: another profile
        self.q0, self.dq, self.motion_id = m.q0, m.dq, m.motion_id
        self.s0, self.v0 = m.fraction(t_s), m.rate(t_s)
        self.acc = m.acc if m.acc > 0 else 1.0 / max(m.ta, 1e-3) ** 2
        self.t0 = t_s
        self.duration = self.v0 / self.acc
        self.q1 = self.q0 + self.dq * min(1.0, self.s0 + 0.5 * self.v0 * self.duration)

    def fraction(self, t_s: float) -> float:
        tau = min(max(t_s - self.t0, 0.0), self.duration)
        return min(1.0, self.s0 + self.v0 * tau - 0.5 * self.acc * tau * tau)


class KarelController:
    """The controller + KAREL serial server; see the module docstring.

    ``model`` is the robot in its BASE frame; ``q0_deg`` the joint angles at power-up;
    ``rigid_body`` the arm twin's rigid-body backend (:class:`droid.arm.arm_dynamics.ArmDynamics`).
    Drive it with :meth:`receive` (host bytes), :meth:`advance` (time) and
    :meth:`transmit` (bytes for the host); read :attr:`q_deg`.
    """

    def __init__(self, model: RobotModel, params: KarelParams | None = None, q0_deg=None,
                 rigid_body: str = "pinocchio") -> None:
        self.model = model
        self.p = params or KarelParams()
        self.q_cmd_deg = np.zeros(6) if q0_deg is None else np.asarray(q0_deg, float).copy()
        if self.q_cmd_deg.shape != (6,) or not model.within_limits(self.q_cmd_deg):
            raise ValueError("karel: the power-up joint angles must be 6 values inside the joint limits")
        self.arm = None
        if self.p.dynamics:
            from droid.arm.arm_dynamics import ArmDynamics

            self.arm = ArmDynamics(model, self.q_cmd_deg, rigid_body)
        self._done_pending: tuple[int, float] | None = None  # (motion id, path end [s]): DONE after in-position
        self.q_deg = self.q_cmd_deg.copy()  # the links (the truth)
        self.q_motor_deg = self.q_cmd_deg.copy()  # what the encoder cards count [joint deg]
        self.home_deg = np.zeros(6)
        self.rx = PacedLine(self.p.baud, self.p.line_capacity_bytes)
        self.tx = PacedLine(self.p.baud, 1 << 16)
        self._partial = kw.LineSplitter()
        self._vlim = model.vmax_deg_s * self.p.joint_speed_fraction
        self.motion: Motion | None = None
        self.last_motion_id = 0
        self.last_duration_s = 0.0  # planned duration of the last accepted motion [s]
        self._interp_free_s = 0.0  # the interpreter can read the next line from this time on
        self._replies: list[tuple[float, bytes]] = []  # (due time [s], bytes), in time order
        self.t_s = 0.0
        self.moved = True  # q_deg changed since the flag was last cleared (cards need an update)
        # counters
        self.lines = 0
        self.accepted = 0
        self.busy_rejects = 0
        self.errors = 0
        self.completed = 0
        self.halts = 0

    # -- the host side ------------------------------------------------------------
    def receive(self, data: bytes, t_s: float) -> None:
        """Bytes written by the host, handed to the line at ``t_s`` [s] (they arrive at line rate)."""
        if self.rx.push(data, t_s):
            self._queue_reply(t_s, kw.Reply(kw.ERR, 0, code=kw.ERR_OVERRUN))

    def transmit(self, t_s: float) -> bytes:
        """Reply bytes whose stop bit has ended by ``t_s`` [s]."""
        return self.tx.pop_due(t_s)[0]

    # -- time ------------------------------------------------------------------------
    def advance(self, t_s: float) -> None:
        """Run the controller up to ``t_s`` [s]: lines that arrived, motion, replies due."""
        arm = self.arm
        if (arm is not None and self.motion is None and self._done_pending is None and not self._replies
                and self.rx.empty and arm.resting_on(self.q_cmd_deg)):
            # idle (the holder of a trial): no line, no reply, no motion, the arm at rest on its
            # reference -- what the steps below would do, the clocks moved (issue 44)
            arm.t_s = t_s
            self.t_s = t_s
            return
        data, start_bits = self.rx.pop_due(t_s)
        if data:
            self._take_bytes(data, start_bits)
        self._release_replies(t_s)
        if self.motion is not None:
            m = self.motion
            self.q_cmd_deg = m.q_at(t_s)
            if self.arm is None:
                self.q_deg = self.q_cmd_deg
                self.q_motor_deg = self.q_cmd_deg
                self.moved = True
            if t_s >= m.t_end:
                self.motion = None
                self.completed += 1
        if self.arm is not None:
            if self.arm.advance(t_s, self.q_cmd_deg):
                self.q_deg = self.arm.q_deg
                self.q_motor_deg = self.arm.q_motor_deg
                self.moved = True
            pending = self._done_pending
            if pending is not None and t_s >= pending[1] and self.in_position():
                self._done_pending = None
                self._queue_reply(t_s, kw.Reply(kw.DONE, pending[0]))
                self._release_replies(t_s)
        self.t_s = t_s

    def _take_bytes(self, data: bytes, start_bits: int) -> None:
        pos = 0
        for m in _TERM.finditer(data):
            end = m.end()
            t_line = self.rx.bits_to_s(start_bits + end * kw.BITS_PER_BYTE)
            for line in self._partial.feed(data[pos:end]):
                self._line(line, t_line)
            pos = end
        if pos < len(data):
            # an unfinished line; the splitter hands back a line that is already too long
            t_end = self.rx.bits_to_s(start_bits + len(data) * kw.BITS_PER_BYTE)
            for line in self._partial.feed(data[pos:]):
                self._line(line, t_end)

    def _release_replies(self, t_s: float) -> None:
        while self._replies and self._replies[0][0] <= t_s:
            due, raw = self._replies.pop(0)
            self.tx.push(raw, due)

    def _queue_reply(self, t_s: float, reply: kw.Reply) -> None:
        raw = kw.format_reply(reply)
        i = len(self._replies)
        while i and self._replies[i - 1][0] > t_s:
            i -= 1
        self._replies.insert(i, (t_s, raw))

    # -- the interpreter ----------------------------------------------------------------
    def moving_at(self, t_s: float) -> bool:
        if self._done_pending is not None:
            return True
        return self.motion is not None and t_s < self.motion.t_end

    def in_position(self) -> bool:
        """Every motor within ``inpos_deg`` of the path [deg] (always, for the ideal arm)."""
        return float(np.max(np.abs(self.q_motor_deg - self.q_cmd_deg))) <= self.p.inpos_deg

    def q_at(self, t_s: float) -> np.ndarray:
        """The interpolated path at ``t_s`` [deg] (the controller plans from it, not from the arm)."""
        return self.motion.q_at(t_s) if self.motion is not None else self.q_cmd_deg

    def _line(self, line: bytes, t_line: float) -> None:
        self.lines += 1
        if line.split(None, 1)[:1] == [kw.HALT.encode()]:  # taken at once (a condition handler's HOLD)
            return self._halt(line, t_line)
        if t_line < self._interp_free_s:
            # the interpreter is still in the previous cycle: the front end only reads the id
            self.busy_rejects += 1
            rid = _peek_id(line)
            self._queue_reply(t_line + self.p.reply_delay_s,
                              kw.Reply(kw.BUSY, rid) if rid else kw.Reply(kw.ERR, 0, code=kw.ERR_SYNTAX))
            return
        self._interp_free_s = t_line + 1.0 / self.p.cycle_hz
        t_reply = t_line + self.p.reply_delay_s
        req = self._parsed(line, t_reply)
        if req is None:
            return
        if req.verb == kw.STAT:
            state = kw.MOVING if self.moving_at(t_line) else kw.IDLE
            self._queue_reply(t_reply, kw.Reply(kw.STAT, req.cmd_id, state=state, motion_id=self.last_motion_id))
            return
        if self.moving_at(t_line):
            self.busy_rejects += 1
            self._queue_reply(t_reply, kw.Reply(kw.BUSY, req.cmd_id))
            return
        q_now = self.q_at(t_line)
        try:
            q_goal = self._goal(req, q_now)
        except Unreachable:
            self.errors += 1
            self._queue_reply(t_reply, kw.Reply(kw.ERR, req.cmd_id, code=kw.ERR_RANGE))
            return
        duration = max(self.min_duration_s(q_now, q_goal), req.duration_s or 0.0)
        # the previous motion (if any) has ended by t_line: settle on its goal first
        if self.motion is not None:
            self.q_cmd_deg = self.motion.q1.copy()
            if self.arm is None:
                self.q_deg = self.q_motor_deg = self.q_cmd_deg
            self.motion = None
            self.completed += 1
        self.motion = Motion(q_now, q_goal, t_reply, duration, self.p.ramp_s, req.cmd_id)
        self.last_motion_id = req.cmd_id
        self.last_duration_s = duration
        self.accepted += 1
        self._queue_reply(t_reply, kw.Reply(kw.ACK, req.cmd_id, seconds=duration))
        if self.arm is None:
            self._queue_reply(t_reply + duration, kw.Reply(kw.DONE, req.cmd_id))
        else:
            self._done_pending = (req.cmd_id, t_reply + duration)

    def _parsed(self, line: bytes, t_reply: float):
        """The request of ``line``, or None after queueing its ``ERR`` reply (a garbled line)."""
        try:
            return kw.parse_request(line)
        except kw.WireError as exc:
            self.errors += 1
            self._queue_reply(t_reply, kw.Reply(kw.ERR, exc.cmd_id, code=exc.code))
            return None

    def _halt(self, line: bytes, t_line: float) -> None:
        """``HALT id``: the motion in progress ends along its path at its deceleration; ``ACK id s``
        (s: until it stands), its ``DONE`` when it stands (issue 41)."""
        t_reply = t_line + self.p.reply_delay_s
        req = self._parsed(line, t_reply)
        if req is None:
            return
        m = self.motion
        if m is None or t_line >= m.t_end:
            self._queue_reply(t_reply, kw.Reply(kw.ACK, req.cmd_id, seconds=0.0))
            return
        self.halts += 1
        h = Halting(m, t_line)
        self.motion = h
        done = kw.format_reply(kw.Reply(kw.DONE, m.motion_id))
        self._replies = [(t, raw) for t, raw in self._replies if raw != done]  # its DONE comes earlier now
        if self.arm is None:
            self._queue_reply(h.t_end, kw.Reply(kw.DONE, m.motion_id))
        elif self._done_pending is not None:
            self._done_pending = (self._done_pending[0], h.t_end)
        self._queue_reply(t_reply, kw.Reply(kw.ACK, req.cmd_id, seconds=h.duration))

    def _goal(self, req: kw.Request, q_now: np.ndarray) -> np.ndarray:
        if req.verb == kw.HOME:
            return self.home_deg.copy()
        if req.verb == kw.JMOVE:
            q = np.array(req.values, float)
            why = self.model.limit_violation(q)
            if why:
                raise Unreachable(why)
            return q
        T = pose_to_T(*req.values)
        return self.model.ik(T, q_now)

    def min_duration_s(self, q_from, q_to) -> float:
        """Shortest duration [s] of a move from ``q_from`` to ``q_to`` [deg] under the speed limits."""
        q_from = np.asarray(q_from, float)
        q_to = np.asarray(q_to, float)
        t_joint = float(np.max(np.abs(q_to - q_from) / self._vlim))
        p0 = self.model.fk(q_from)[:3, 3]
        p1 = self.model.fk(q_to)[:3, 3]
        t_lin = float(np.linalg.norm(p1 - p0)) / self.p.speed_mm_s
        cruise = max(t_joint, t_lin)
        ramp = self.p.ramp_s
        return cruise + ramp if cruise >= ramp else 2.0 * cruise


def _peek_id(line: bytes) -> int:
    """The id field of a request line if it is readable, else 0."""
    f = kw.fields(line[: kw.MAX_LINE + 1])
    if len(f) >= 2:
        try:
            return kw._parse_id(f[1])
        except kw.WireError:
            return 0
    return 0
