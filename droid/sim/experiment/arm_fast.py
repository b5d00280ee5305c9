"""The ``fast`` Reis model for the trial harness: the real planner chain, an analytic servo.

What a cartesian command goes through in the real-time cell (docs/reis.md,
thesis §4.1.5-4.1.8, and droid.sim.reis_cell which runs those cores in
lockstep), and what this model keeps:

1. the task writes the Brain Command at tick k; the remote/agent copy it into
   the controller at tick k+1 (kept: one tick);
2. the planner (§4.1.7) solves the 8 inverse solutions and picks one against
   its current way-point (eq. 4.15, :meth:`RobotModel.ik`) -- kept exactly,
   so the configuration and wrist effects of the real pick appear; an
   unreachable command is refused and the arm holds; then it interpolates
   ``int + (ext - int) / joint_time_count`` per tick (kept, in degrees
   instead of whole counts: 1 count = 0.0009 deg);
3. the servo agent sends the way-point half a tick later; the servo's planner
   ramps to it over one command period, its displacement clipped to the
   joint's maximum speed (§4.1.5.2; kept: the reference is that ramp,
   ``ServoParams.max_speed_counts_per_tick``);
4. the 500 Hz PID and the plant make the joint follow the reference -- here
   a linear closed loop per joint, ``y'' = wn^2 (r - y) + 2 zeta wn (r' - y')``
   (type 2: no steady error on a ramp, as the PID's integral gives), solved
   exactly on each ramp (the tracking error ``e = y - r`` evolves freely
   within a ramp; at a breakpoint ``e'`` jumps by minus the slope change).
   ``wn`` and ``zeta`` are calibrated against the ``full`` model (the real
   servo core and plant), docs/experiments.md.  Not modelled: amplifier
   saturation, gravity sag, following-error faults, braking;
5. the Status: the servo publishes its encoder positions at 125 Hz (every 4th
   servo tick, at 6 ms + 8 ms j), the servo agent copies the newest into the
   controller Status half a tick before the heartbeat tick, the remote's FK
   turns them into the Brain Status pose (§4.1.8) -- kept: the Status at tick
   k holds the joints at the newest 125 Hz sample before ``t_k - T/2``.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from droid.kinematics import RobotModel, Unreachable
from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.servo_wire import STATUS_EVERY_TICKS

HEARTBEAT_HZ = 60.0


@dataclass(frozen=True)
class FastArmParams:
    """Closed-loop servo model and Status timing (calibrated against the full model)."""

    natural_hz: float = 12.0  # wn / 2 pi [Hz]
    damping: float = 0.9  # zeta
    heartbeat_hz: float = HEARTBEAT_HZ
    status_sampling: bool = True  # the Status holds the 125 Hz servo sample before t_k - T/2


def _transition(wn: float, zeta: float, h: float) -> np.ndarray:
    """State transition of e'' = -wn^2 e - 2 zeta wn e' over h seconds (2x2 matrix exponential)."""
    a = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
    n = max(0, int(math.ceil(math.log2(max(1e-12, np.abs(a).max() * max(h, 1e-12))))) + 4)
    m = a * (h / 2 ** n)
    out = np.eye(2)
    term = np.eye(2)
    for k in range(1, 16):
        term = term @ m / k
        out = out + term
    for _ in range(n):
        out = out @ out
    return out


class _Ramp:
    """One servo reference ramp: from ``r0`` at slope ``v`` from ``t0_ns``, with the tracking error state."""

    __slots__ = ("t0_ns", "r0", "v", "e", "ed")

    def __init__(self, t0_ns: int, r0, v, e, ed) -> None:
        self.t0_ns, self.r0, self.v, self.e, self.ed = t0_ns, r0, v, e, ed


class FastArm:
    """The Reis as the trial harness drives it (see the module docstring)."""

    def __init__(self, model: RobotModel, q_start_deg, params: FastArmParams = FastArmParams(),
                 servo: ServoParams = ServoParams()) -> None:
        self.model = model
        self.p = params
        self.period_ns = int(round(1e9 / params.heartbeat_hz))
        self.period_s = self.period_ns / 1e9
        self.half_ns = self.period_ns // 2
        self._wn = 2.0 * math.pi * params.natural_hz
        self._phi_cache: dict[int, np.ndarray] = {}
        cpd = np.abs(np.diag(model.gearing.joint_to_counts_matrix))
        self.vmax_deg_s = np.asarray(servo.max_speed_counts_per_tick, float) * servo.servo_rate_hz / cpd
        self.status_period_ns = int(round(STATUS_EVERY_TICKS * 1e9 / servo.servo_rate_hz))
        self.status_phase_ns = int(round((STATUS_EVERY_TICKS - 1) * 1e9 / servo.servo_rate_hz))
        q0 = np.asarray(q_start_deg, float).copy()
        self.q_int = q0.copy()  # the planner's current way-point [deg]
        self.q_ext = q0.copy()  # the command's target [deg]
        self.time_count = 0
        self._mailbox: tuple[np.ndarray, int] | None = None  # written by the task, planned next tick
        self.refused = 0
        self.last_refusal = ""
        self._sent = q0.copy()  # the servo's last (speed-clipped) target
        z = np.zeros(6)
        self._ramps: deque[_Ramp] = deque([_Ramp(-self.half_ns, q0.copy(), z, z, z)], maxlen=4)
        self.ticks = 0
        self.t_ns = 0
        self.q = q0.copy()  # true joints at the last tick [deg]
        self.q_status = q0.copy()  # joints the Status holds at the last tick [deg]

    # -- what the task side sees and does -------------------------------------
    def command_cart(self, T_global_wcp, ticks: int) -> None:
        """A cartesian command (WCP pose, global, 4x4 mm) to complete in ``ticks`` heartbeat ticks."""
        self._mailbox = (np.asarray(T_global_wcp, float).copy(), max(int(ticks), 1))

    def status_pose(self) -> np.ndarray:
        """The Brain Status pose at this tick: FK of the sampled joints (4x4, global, mm)."""
        return self.model.fk(self.q_status)

    def status_joints(self) -> np.ndarray:
        return self.q_status.copy()

    def true_wcp(self) -> np.ndarray:
        """The true wrist-centre pose at this tick (the arm-twin interface, 4x4 mm)."""
        return self.model.fk(self.q)

    # -- time evolution ----------------------------------------------------------
    def _phi(self, dt_ns: int) -> np.ndarray:
        """Transition over ``dt_ns`` (to the microsecond: the tick times repeat, so a handful of values)."""
        key = int(round(dt_ns / 1000))
        phi = self._phi_cache.get(key)
        if phi is None:
            phi = self._phi_cache[key] = _transition(self._wn, self.p.damping, key / 1e6)
        return phi

    def q_at(self, t_ns: int) -> np.ndarray:
        """Joint angles [deg] at time ``t_ns`` (within the last few ramps)."""
        for ramp in reversed(self._ramps):
            if ramp.t0_ns <= t_ns:
                break
        dt = t_ns - ramp.t0_ns
        phi = self._phi(dt)
        return ramp.r0 + ramp.v * (dt / 1e9) + phi[0, 0] * ramp.e + phi[0, 1] * ramp.ed

    def tick(self) -> None:
        """Advance to the next heartbeat tick: joints, Status sample, planner, next servo ramp."""
        self.ticks += 1
        self.t_ns = int(round(self.ticks * 1e9 / self.p.heartbeat_hz))
        self.q = self.q_at(self.t_ns)
        if self.p.status_sampling:
            t_agent = self.t_ns - self.half_ns
            t_s = self.status_phase_ns + self.status_period_ns * ((t_agent - self.status_phase_ns)
                                                                  // self.status_period_ns)
            self.q_status = self.q_at(t_s)
        else:
            self.q_status = self.q
        if self._mailbox is not None:  # the remote/agent deliver last tick's command to the planner
            T, ticks = self._mailbox
            self._mailbox = None
            try:
                target = self.model.ik(T, self.q_int)
            except (Unreachable, ValueError) as exc:
                self.refused += 1
                self.last_refusal = str(exc)
            else:
                self.q_ext = target
                self.time_count = ticks
        if self.time_count > 1:  # plan_joint_cmd(): the next way-point
            self.q_int = self.q_int + (self.q_ext - self.q_int) / self.time_count
        else:
            self.q_int = self.q_ext.copy()
        if self.time_count > 0:
            self.time_count -= 1
        self._next_ramp(self.t_ns + self.half_ns)

    def _next_ramp(self, t0_ns: int) -> None:
        """The servo agent's send half a tick after the tick: the next ramp (speed-clipped)."""
        last = self._ramps[-1]
        dt = t0_ns - last.t0_ns
        phi = self._phi(dt)
        e = phi[0, 0] * last.e + phi[0, 1] * last.ed
        ed = phi[1, 0] * last.e + phi[1, 1] * last.ed
        r_end = last.r0 + last.v * (dt / 1e9)
        lim = self.vmax_deg_s * self.period_s
        self._sent = self._sent + np.clip(self.q_int - self._sent, -lim, lim)
        v_new = (self._sent - r_end) / self.period_s
        self._ramps.append(_Ramp(t0_ns, r_end, v_new, e, ed - (v_new - last.v)))
