"""The Joystick program's core: a joystick's axes and buttons -> jog commands for one arm (§3.4).

"The Joystick program is a generic robot program which is used to command
robot movement in Joint mode or Cartesian mode using an analog joystick. ...
Use of the Joystick program is not only limited after the homing routine, but
is available prior to homing" (thesis §3.4).  ``droid-jog ROBOT --joystick
SUBUNIT`` runs this core once per heartbeat tick on the joystick's Brain
Status (a task sees the Brain's databases only).

The thesis's stick has two analog axes and eight buttons; the mapping:

* axis 0 and axis 1 drive a *pair* of the arm's axes: pair 0 = joints 1, 2
  (cartesian: x, y), pair 1 = joints 3, 4 (z, A), pair 2 = joints 5, 6 (B, C);
* buttons 0, 1, 2 select pair 0, 1, 2; button 3 toggles joint/cartesian mode
  (on press); button 7 ends the program;
* a deflection d (|d| > ``deadband``) moves a joint at
  ``d * joint_fraction * vmax`` [deg/s] (as encoder counts: JOG mode, works
  before homing), a cartesian axis at ``d * cart_mm_s`` [mm/s] or
  ``d * cart_deg_s`` [deg/s] (needs a homed arm: the pose is known only then).

Nothing moves while the joystick's Status is invalid or stale (a dead-man:
the stick unplugged or its link down), and a new command goes out only after
the previous one was delivered (the Brain's ``sent`` flag cleared, Table 3.2),
so no jog is overwritten before the remote copied it; the motion accumulated
meanwhile goes out with the next one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from droid.kinematics import Unreachable
from droid.kinematics.transforms import T_to_pose, pose_to_T

PAIRS = ((0, 1), (2, 3), (4, 5))  # arm axes driven by stick axes 0 and 1
BUTTON_PAIR = (0, 1, 2)  # buttons selecting pair 0, 1, 2
BUTTON_MODE = 3  # toggles joint / cartesian on press
BUTTON_QUIT = 7  # ends the program
CART_PERIOD_S = 0.1  # a cartesian jog is a short move of this duration [s]


@dataclass
class StickInput:
    """One sample of the joystick's Brain Status."""

    axes: tuple  # deflections -1..1
    buttons: tuple  # 0/1
    valid: bool
    stale: bool


@dataclass
class StickAction:
    """What the shell does this tick: nothing, a joint jog, a cartesian move, or quit."""

    kind: str  # "none", "jog", "cart", "quit"
    delta_counts: np.ndarray | None = None  # jog: relative encoder counts (6,)
    T: np.ndarray | None = None  # cart: 4x4 target (mm)
    ticks: int = 0  # cart: move time [heartbeat ticks]
    note: str = ""  # a line for the operator (mode change, refusal)


class StickJog:
    """Joystick samples in, jog commands out (no I/O); see the module docstring."""

    def __init__(self, model, hb_hz: float, *, cart: bool = False, deadband: float = 0.1,
                 joint_fraction: float = 0.25, cart_mm_s: float = 50.0, cart_deg_s: float = 10.0) -> None:
        self.model = model
        self.hb_hz = float(hb_hz)
        self.cart = cart
        self.pair = 0
        self.deadband = deadband
        self.joint_fraction = joint_fraction
        self.cart_mm_s = cart_mm_s
        self.cart_deg_s = cart_deg_s
        self._prev_buttons = (0,) * 16
        self._counts_acc = np.zeros(6)  # joint motion not yet sent [counts]
        self._cart_acc = np.zeros(6)  # cartesian motion not yet sent [mm, deg]
        self._cart_wait_s = 0.0
        self._target = None  # cartesian: the last pose commanded (x y z mm, A B C deg)
        cpd = np.abs(np.diag(np.asarray(model.gearing.joint_to_counts_matrix, float)))
        self._counts_per_s = joint_fraction * np.asarray(model.vmax_deg_s, float) * cpd  # at full deflection

    def _deflection(self, v: float) -> float:
        if abs(v) <= self.deadband:
            return 0.0
        # rescale so the speed starts from 0 at the edge of the dead band
        return (abs(v) - self.deadband) / (1.0 - self.deadband) * (1.0 if v > 0 else -1.0)

    def step(self, dt_s: float, stick: StickInput, homed: bool, delivered: bool,
             q_deg=None) -> StickAction:
        """One tick: ``dt_s`` [s] since the last, the stick, the arm's ``homed``, whether the
        last command was delivered, and the arm's joint angles [deg] (for cartesian mode)."""
        buttons = tuple(stick.buttons) + (0,) * (16 - len(stick.buttons))
        pressed = [b and not p for b, p in zip(buttons, self._prev_buttons)]
        self._prev_buttons = buttons
        note = ""
        if not stick.valid or stick.stale:
            self._counts_acc[:] = 0.0
            self._cart_acc[:] = 0.0
            return StickAction("none")
        if pressed[BUTTON_QUIT]:
            return StickAction("quit", note="quit (button 7)")
        for pair, b in enumerate(BUTTON_PAIR):
            if pressed[b]:
                self.pair = pair
                note = f"axes: {'x y / z A / B C'.split(' / ')[pair] if self.cart else PAIR_NAMES[pair]}"
        if pressed[BUTTON_MODE]:
            self.cart = not self.cart
            self._counts_acc[:] = 0.0
            self._cart_acc[:] = 0.0
            self._target = None
            note = f"mode: {'cartesian' if self.cart else 'joint'}"
        a, b = PAIRS[self.pair]
        d = (self._deflection(float(stick.axes[0])), self._deflection(float(stick.axes[1])))
        if not self.cart:
            self._counts_acc[a] += d[0] * self._counts_per_s[a] * dt_s
            self._counts_acc[b] += d[1] * self._counts_per_s[b] * dt_s
            whole = np.trunc(self._counts_acc)
            if not delivered or not whole.any():
                return StickAction("none", note=note)
            self._counts_acc -= whole
            return StickAction("jog", delta_counts=whole.astype(np.int32), note=note)
        # cartesian
        if not homed or q_deg is None:
            if d != (0.0, 0.0):
                return StickAction("none", note="cartesian jogging needs a homed arm (button 3: joint mode)")
            return StickAction("none", note=note)
        speed = np.array([self.cart_mm_s] * 3 + [self.cart_deg_s] * 3)
        self._cart_acc[a] += d[0] * speed[a] * dt_s
        self._cart_acc[b] += d[1] * speed[b] * dt_s
        self._cart_wait_s += dt_s
        if not self._cart_acc.any():  # stick centred: the next jog starts from where the arm is
            self._target = None
            self._cart_wait_s = 0.0
            return StickAction("none", note=note)
        if not delivered or self._cart_wait_s < CART_PERIOD_S:
            return StickAction("none", note=note)
        self._cart_wait_s = 0.0
        if self._target is None:
            self._target = T_to_pose(self.model.fk(np.asarray(q_deg, float)))
        pose = self._target + self._cart_acc
        self._cart_acc[:] = 0.0
        T = pose_to_T(*pose)
        try:
            self.model.ik(T, np.asarray(q_deg, float))
        except Unreachable as exc:
            return StickAction("none", note=f"refused: {exc.reason}")
        self._target = pose
        ticks = max(1, int(round(CART_PERIOD_S * self.hb_hz)))
        return StickAction("cart", T=T, ticks=ticks, note=note)


PAIR_NAMES = ("j1 j2", "j3 j4", "j5 j6")
