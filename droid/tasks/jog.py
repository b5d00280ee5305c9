"""droid-jog ROBOT: move an arm by hand, in place of the thesis's joystick (§3.4).

"The Joystick program is a generic robot program which is used to command
robot movement in Joint mode or Cartesian mode ... Use of the Joystick program
is not only limited after the homing routine, but is available prior to homing
in the event the robot must be moved to a safe location prior to homing."

Keyboard (stdin is a terminal): one key per step, like a joystick deflection::

    joint mode:  a/z joint 1 +/-   s/x joint 2   d/c joint 3
                 f/v joint 4       g/b joint 5   h/n joint 6
    cart mode:   a/z x +/-   s/x y   d/c z   (mm)   f/v A   g/b B   h/n C (ZYZ deg)
    m  toggle joint/cartesian    +/-  double/halve the step    q or Esc  quit

Lines (stdin is a pipe or file), one command a line, for scripts::

    j1 +500        joint 1 by +500 encoder counts (j1..j6)
    x -2.5         wrist centre x by -2.5 mm (x, y, z), global frame
    b 5            ZYZ angle B by +5 deg (a, b, c)
    wait 0.5       pause [s]
    # comment

Joystick (``--joystick SUBUNIT``, a subunit of class ``joystick``): the thesis's
Joystick program (§3.4), in :mod:`droid.tasks.stick`: axis 0/1 drive joints 1/2
(cartesian x/y), buttons 0-2 select the pair (j1 j2, j3 j4, j5 j6; x y, z A, B C),
button 3 toggles joint/cartesian, button 7 quits (or ``--seconds``, or Ctrl-C).

Joint jogs are JOG-mode commands: relative encoder counts (thesis §3.3) that
work before homing.  Cartesian jogs need a homed arm (the pose is only known
then) and are sent as short cartesian moves, checked for reach and limits
first.  A bad line gets a one-line error and is skipped; the exit code is then 2.
"""
from __future__ import annotations

import math
import os
import select
import sys
import time

import numpy as np

from droid.brain.db.databases import open_brain
from droid.brain.runtime.program import open_cell, parser
from droid.brain.runtime.rt import PeriodicTimer
from droid.cli import BadInput, RuntimeFailure, bounded_float, bounded_int, duration_s, parse_finite, run
from droid.kinematics.transforms import T_to_pose, pose_to_T
from droid.tasks.arm import BrainArm
from droid.tasks.stick import StickInput, StickJog

PROG = "droid-jog"
KEYS = "azsxdcfvgbhn"  # pairs (+, -) for axes 1..6
JOINT_AXES = ("j1", "j2", "j3", "j4", "j5", "j6")
CART_AXES = ("x", "y", "z", "a", "b", "c")
MIN_MOVE_S = 0.1  # a cartesian jog takes at least this long
JOG_SPEED_FRACTION = 0.5  # joint jogs run at half the joint's velocity limit
JOG_ACCEL_DEG_S2 = 300.0  # and accelerate gently (the servo limits JOG acceleration too)
APPLY_TIMEOUT_S = 2.0
JOG_CORRECTIONS = 3


class Jogger:
    """Turns jog requests into commands for one arm (through the Brain's databases)."""

    def __init__(self, arm: BrainArm, step_counts: int, step_mm: float, step_deg: float) -> None:
        self.arm = arm
        self.step_counts = step_counts
        self.step_mm = step_mm
        self.step_deg = step_deg
        self.cart = False

    def joint(self, axis: int, delta_counts: int) -> None:
        """Jog one joint by ``delta_counts`` [counts], as a trapezoidal series of per-tick
        JOG commands (the servo planner clips a JOG step to what the joint can do in one
        command period, thesis §4.1.5.2, so a large step is split here)."""
        delta = np.zeros(6, np.int32)
        delta[axis] = int(delta_counts)
        rec = self.arm.read()
        self.arm.check_fresh(rec)
        target = np.asarray(rec["encoder_pos"], float) + delta
        if int(rec["homed"]):
            lo, hi = np.asarray(self.arm.model.counts_min), np.asarray(self.arm.model.counts_max)
            if not lo[axis] <= target[axis] <= hi[axis]:
                raise BadInput(f"joint {axis + 1} would go to {int(target[axis])} counts, outside "
                               f"[{int(lo[axis])}, {int(hi[axis])}]")
        cpd = abs(float(self.arm.model.gearing.joint_to_counts_matrix[axis, axis]))  # counts/deg
        vmax = JOG_SPEED_FRACTION * float(self.arm.model.vmax_deg_s[axis]) * cpd
        goal = int(rec["encoder_cmd"][axis]) + int(delta_counts)
        remaining = int(delta_counts)
        for _ in range(JOG_CORRECTIONS + 1):
            for step in trapezoid_steps(remaining, vmax, JOG_ACCEL_DEG_S2 * cpd, 1.0 / self.arm.hb_hz):
                chunk = np.zeros(6, np.int32)
                chunk[axis] = step
                cmd_id = self.arm.command_jog(chunk)
                # one command reaches the servo per heartbeat tick: wait until it is applied
                self.arm.wait(lambda r: int(r["cmd_id"]) == cmd_id, APPLY_TIMEOUT_S, f"jog {cmd_id} applied")
            # The servo may clip a step (speed/acceleration limits of a JOG, §4.1.5.2):
            # look where its command ended up, like an operator on a joystick, and correct.
            ticks = 0
            while True:
                a = int(self.arm.read()["encoder_cmd"][axis])
                time.sleep(2.0 / self.arm.hb_hz)
                b = int(self.arm.read()["encoder_cmd"][axis])
                ticks += 1
                if a == b or ticks > 30:
                    break
            remaining = goal - b
            if abs(remaining) <= 1:
                return

    def cartesian(self, axis: int, delta: float) -> None:
        rec = self.arm.read()
        self.arm.check_fresh(rec)
        if not int(rec["homed"]):
            raise BadInput("cartesian jogging needs a homed arm (joint jogging works before homing)")
        q = self.arm.joints_deg(rec)
        pose = T_to_pose(self.arm.model.fk(q))
        pose[axis] += delta
        vmax = np.asarray(self.arm.model.vmax_deg_s, float)
        T, q_new = self.arm.check_cart_target(pose, 1e9, q)  # reach and limits; speed below
        seconds = max(MIN_MOVE_S, float(np.max(np.abs(q_new - q) / vmax)) * 1.05)
        cmd_id = self.arm.command_cart(pose_to_T(*pose), self.arm.ticks_for(seconds))
        self.arm.wait(lambda r: int(r["cmd_id"]) == cmd_id, APPLY_TIMEOUT_S, f"jog {cmd_id} accepted")

    def key(self, ch: str) -> str | None:
        """Handle one key; returns a status line or None; 'quit' to stop."""
        if ch in ("q", "\x1b", "\x03", "\x04"):
            return "quit"
        if ch == "m":
            self.cart = not self.cart
            return f"mode: {'cartesian' if self.cart else 'joint'}"
        if ch in "+-":
            f = 2.0 if ch == "+" else 0.5
            self.step_counts = max(1, int(self.step_counts * f))
            self.step_mm *= f
            self.step_deg *= f
            return f"step: {self.step_counts} counts, {self.step_mm:g} mm, {self.step_deg:g} deg"
        i = KEYS.find(ch)
        if i < 0:
            return None
        axis, sign = i // 2, (1 if i % 2 == 0 else -1)
        if self.cart:
            self.cartesian(axis, sign * (self.step_mm if axis < 3 else self.step_deg))
        else:
            self.joint(axis, sign * self.step_counts)
        return None

    def line(self, text: str) -> None:
        words = text.split("#", 1)[0].split()
        if not words:
            return
        if words[0] == "wait" and len(words) == 2:
            t = _number(words[1])
            if not t >= 0:
                raise BadInput(f"wait needs seconds >= 0, got {words[1]!r}")
            time.sleep(t)
            return
        if len(words) != 2:
            raise BadInput(f"expected 'AXIS DELTA' (e.g. 'j2 +500', 'x -2.5'), got {text.strip()!r}")
        name, value = words[0].lower(), _number(words[1])
        if name in JOINT_AXES:
            if value != round(value):
                raise BadInput(f"joint jogs are whole encoder counts, got {words[1]!r}")
            self.joint(JOINT_AXES.index(name), int(value))
        elif name in CART_AXES:
            self.cartesian(CART_AXES.index(name), value)
        else:
            raise BadInput(f"unknown axis {words[0]!r} (j1..j6, x y z [mm], a b c [deg])")


def trapezoid_steps(distance: int, vmax: float, accel: float, dt: float) -> list[int]:
    """Per-tick increments [counts] covering ``distance`` [counts] with speed <= ``vmax``
    [counts/s] and acceleration/deceleration <= ``accel`` [counts/s^2]; they sum exactly."""
    sign = 1 if distance >= 0 else -1
    left = abs(int(distance))
    steps, v = [], 0.0
    while left > 0:
        v = min(vmax, v + accel * dt, math.sqrt(2.0 * accel * left) + accel * dt)
        step = min(left, max(1, int(v * dt)))
        steps.append(sign * step)
        left -= step
    return steps


def _number(text: str) -> float:
    try:
        return parse_finite(text)
    except ValueError as exc:
        raise BadInput(str(exc)) from None


def _keyboard(jog: Jogger) -> int:
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    print(__doc__.split("Keyboard", 1)[1].split("Lines", 1)[0].strip().split("\n", 1)[1], file=sys.stderr)
    try:
        tty.setcbreak(fd)
        while True:
            r, _, _ = select.select([fd], [], [], 0.5)
            if not r:
                continue
            ch = os.read(fd, 1).decode(errors="replace")
            try:
                msg = jog.key(ch)
            except BadInput as exc:
                msg = f"refused: {exc}"
            if msg == "quit":
                return 0
            if msg:
                print(msg, file=sys.stderr, flush=True)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def _jog_from_stick(arm: BrainArm, cell, joy_name: str, cart: bool, seconds: float | None) -> int:
    """Drive ``arm`` from the joystick subunit ``joy_name`` once per heartbeat tick (§3.4)."""
    joy = cell.subunit(joy_name)
    joy.check_class("joystick", "a joystick")
    status = open_brain(cell, joy, "status")
    core = StickJog(arm.model, arm.hb_hz, cart=cart)
    period_ns = int(round(1e9 / arm.hb_hz))
    timer = PeriodicTimer(period_ns, start_ns=time.monotonic_ns())
    t0 = last = time.monotonic()
    last_note = ""
    print(f"{PROG}: {arm.sub.name} from joystick {joy_name} ({'cartesian' if cart else 'joint'} mode; "
          "buttons 0-2 axis pair, 3 joint/cartesian, 7 quit)", file=sys.stderr, flush=True)
    try:
        while seconds is None or time.monotonic() - t0 < seconds:
            if not timer.wait(0.5):
                continue
            now = time.monotonic()
            dt, last = now - last, now
            j = status.read()
            stick = StickInput(tuple(float(v) for v in j["axes"]), tuple(int(v) for v in j["buttons"]),
                               bool(j["valid"]), bool(j["stale"]))
            rec = arm.read()
            with arm.command.locked() as c:
                delivered = not int(c["sent"])
            homed = bool(int(rec["homed"]))
            q = arm.joints_deg(rec) if homed else None
            act = core.step(dt, stick, homed, delivered, q)
            if act.note and act.note != last_note:
                print(f"{PROG}: {act.note}", file=sys.stderr, flush=True)
            last_note = act.note or last_note
            if act.kind == "quit":
                break
            if act.kind == "jog":
                arm.command_jog(act.delta_counts)
            elif act.kind == "cart":
                arm.command_cart(act.T, act.ticks)
    finally:
        timer.close()
        status.close()
    return 0


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Jog an arm from the keyboard, a joystick or command lines on stdin (works before homing).")
    ap.add_argument("robot", help="arm subunit, e.g. arm1")
    ap.add_argument("--cart", action="store_true", help="start in cartesian mode (keyboard)")
    ap.add_argument("--step", type=bounded_int(1, 100_000, "counts"), default=200, metavar="COUNTS",
                    help="joint step per key [encoder counts] (default 200)")
    ap.add_argument("--step-mm", type=bounded_float(0.0, 100.0, "mm", lo_open=True), default=1.0, metavar="MM",
                    help="cartesian step per key [mm] (default 1)")
    ap.add_argument("--step-deg", type=bounded_float(0.0, 90.0, "deg", lo_open=True), default=1.0, metavar="DEG",
                    help="orientation step per key [deg] (default 1)")
    ap.add_argument("--joystick", dest="stick", metavar="SUBUNIT", default=None,
                    help="drive the arm from this joystick subunit (thesis §3.4), e.g. joy")
    ap.add_argument("--seconds", type=duration_s(), default=None, metavar="S",
                    help="with --joystick: stop after S seconds (default: button 7 or Ctrl-C)")
    args = ap.parse_args(argv)
    if args.seconds is not None and args.stick is None:
        ap.error("--seconds needs --joystick")
    cell = open_cell(args)
    if args.stick is not None:  # a bad joystick name: exit 2 before touching the arm
        cell.subunit(args.stick).check_class("joystick", "a joystick")
    with BrainArm(cell, args.robot) as arm:
        arm.connect()
        arm.check_fresh()
        if args.stick is not None:
            try:
                return _jog_from_stick(arm, cell, args.stick, args.cart, args.seconds)
            except KeyboardInterrupt:
                return 0
        jog = Jogger(arm, args.step, args.step_mm, args.step_deg)
        jog.cart = args.cart
        if sys.stdin.isatty():
            return _keyboard(jog)
        bad = 0
        for n, text in enumerate(sys.stdin, 1):
            try:
                jog.line(text)
            except BadInput as exc:
                bad += 1
                print(f"{PROG}: line {n}: {exc}", file=sys.stderr, flush=True)
            except RuntimeFailure:
                raise
        return 2 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
