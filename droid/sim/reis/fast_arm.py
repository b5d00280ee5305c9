"""The ``fast`` Reis model for the trial harness: the real planner chain, an analytic servo.

What a cartesian command goes through in the real-time cell (docs/reis.md,
thesis §4.1.5-4.1.8, and droid.sim.reis.cell which runs those cores in
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

from droid.sim.reis.plant import expm

from droid.kinematics import RobotModel, Unreachable
from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.servo_wire import STATUS_EVERY_TICKS

from droid.brain.cell.device import HEARTBEAT_HZ  # [Hz], the droid-heartbeat declaration


@dataclass(frozen=True)
class FastArmParams:
    """Closed-loop servo model and Status timing (calibrated against the full model)."""

    natural_hz: float = 12.0  # wn / 2 pi [Hz]
    damping: float = 0.9  # zeta
    heartbeat_hz: float = HEARTBEAT_HZ
    status_sampling: bool = True  # the Status holds the 125 Hz servo sample before t_k - T/2


def _transition(wn: float, zeta: float, h: float) -> np.ndarray:
    """State transition of e'' = -wn^2 e - 2 zeta wn e' over h seconds (2x2 matrix exponential)."""
    return expm(np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]]) * h)


class _Ramp:
    """One servo reference ramp: from ``r0`` at slope ``v`` from ``t0_ns``, with the tracking error state.

    Per joint lists of 6 floats [deg, deg/s]: per-tick arithmetic on 6-vectors is
    cheaper in plain floats than in numpy (and the same, operation by operation).
    """

    __slots__ = ("t0_ns", "r0", "v", "e", "ed")

    def __init__(self, t0_ns: int, r0: list, v: list, e: list, ed: list) -> None:
        self.t0_ns, self.r0, self.v, self.e, self.ed = t0_ns, r0, v, e, ed


class FastArm:
    """The Reis as the trial harness drives it (see the module docstring).

    Joint vectors are kept as lists of 6 floats [deg]; the accessors return arrays.
    """

    def __init__(self, model: RobotModel, q_start_deg, params: FastArmParams | None = None,
                 servo: ServoParams = ServoParams()) -> None:
        params = FastArmParams() if params is None else params  # None: the calibrated defaults (a trial's)
        self.model = model
        self.p = params
        self.period_ns = int(round(1e9 / params.heartbeat_hz))
        self.period_s = self.period_ns / 1e9
        self.half_ns = self.period_ns // 2
        self._wn = 2.0 * math.pi * params.natural_hz
        self._phi_cache: dict[int, tuple[float, float, float, float]] = {}
        cpd = np.abs(np.diag(model.gearing.joint_to_counts_matrix))
        self.vmax_deg_s = np.asarray(servo.max_speed_counts_per_tick, float) * servo.servo_rate_hz / cpd
        self._lim_deg = (self.vmax_deg_s * self.period_s).tolist()  # largest step per period [deg]
        self.status_period_ns = int(round(STATUS_EVERY_TICKS * 1e9 / servo.servo_rate_hz))
        self.status_phase_ns = int(round((STATUS_EVERY_TICKS - 1) * 1e9 / servo.servo_rate_hz))
        q0 = np.asarray(q_start_deg, float).tolist()
        self._q_int = list(q0)  # the planner's current way-point [deg]
        self._q_ext = list(q0)  # the command's target [deg]
        self.time_count = 0
        self._mailbox: tuple[np.ndarray, int] | None = None  # written by the task, planned next tick
        self.refused = 0
        self.last_refusal = ""
        self._sent = list(q0)  # the servo's last (speed-clipped) target
        z = [0.0] * 6
        self._ramps: deque[_Ramp] = deque([_Ramp(-self.half_ns, list(q0), z, z, z)], maxlen=4)
        self.ticks = 0
        self.t_ns = 0
        self._q = list(q0)  # true joints at the last tick [deg]
        self._q_status = list(q0)  # joints the Status holds at the last tick [deg]

    # -- joint vectors as arrays [deg] (alike in shape only: four vectors, each a copy) ----------
    @property
    def q(self) -> np.ndarray:
        """True joints at the last tick [deg]."""
        return np.array(self._q)

    @property
    def q_status(self) -> np.ndarray:
        """Joints the Status holds at the last tick [deg]."""
        return np.array(self._q_status)

    @property
    def q_int(self) -> np.ndarray:
        """The planner's current way-point [deg]."""
        return np.array(self._q_int)

    @property
    def q_ext(self) -> np.ndarray:
        """The planner's target [deg]."""
        return np.array(self._q_ext)

    # -- what the task side sees and does -------------------------------------
    def command_cart(self, T_global_wcp, ticks: int) -> None:
        """A cartesian command (WCP pose, global, 4x4 mm) to complete in ``ticks`` heartbeat ticks."""
        self._mailbox = (np.asarray(T_global_wcp, float).copy(), max(int(ticks), 1))

    def status_pose(self) -> np.ndarray:
        """The Brain Status pose at this tick: FK of the sampled joints (4x4, global, mm)."""
        return self.model.fk(self._q_status)

    def status_joints(self) -> np.ndarray:
        return np.array(self._q_status)

    #: The subunit name the tracker's fault rule names (the layout's tool robot).
    name = "arm1"

    def status_fault(self) -> int:
        """The Status ``fault`` bits: none -- this model has no faults (module docstring, item 4)."""
        return 0

    def true_wcp(self) -> np.ndarray:
        """The true wrist-centre pose at this tick (the arm-twin interface, 4x4 mm)."""
        return self.model.fk(self._q)

    # -- time evolution ----------------------------------------------------------
    def _phi(self, dt_ns: int) -> tuple[float, float, float, float]:
        """Transition (phi00, phi01, phi10, phi11) over ``dt_ns`` (to the microsecond: the tick
        times repeat, so a handful of values)."""
        key = int(round(dt_ns / 1000))
        phi = self._phi_cache.get(key)
        if phi is None:
            m = _transition(self._wn, self.p.damping, key / 1e6)
            phi = self._phi_cache[key] = (float(m[0, 0]), float(m[0, 1]), float(m[1, 0]), float(m[1, 1]))
        return phi

    def _q_at(self, t_ns: int) -> list:
        for ramp in reversed(self._ramps):
            if ramp.t0_ns <= t_ns:
                break
        dt = t_ns - ramp.t0_ns
        p00, p01, _, _ = self._phi(dt)
        x = dt / 1e9
        return [r + v * x + p00 * e + p01 * ed for r, v, e, ed in zip(ramp.r0, ramp.v, ramp.e, ramp.ed)]

    def q_at(self, t_ns: int) -> np.ndarray:
        """Joint angles [deg] at time ``t_ns`` (within the last few ramps)."""
        return np.array(self._q_at(t_ns))

    def tick(self) -> None:
        """Advance to the next heartbeat tick: joints, Status sample, planner, next servo ramp."""
        self.ticks += 1
        self.t_ns = int(round(self.ticks * 1e9 / self.p.heartbeat_hz))
        self._q = self._q_at(self.t_ns)
        if self.p.status_sampling:
            t_agent = self.t_ns - self.half_ns
            t_s = self.status_phase_ns + self.status_period_ns * ((t_agent - self.status_phase_ns)
                                                                  // self.status_period_ns)
            self._q_status = self._q_at(t_s)
        else:
            self._q_status = self._q
        if self._mailbox is not None:  # the remote/agent deliver last tick's command to the planner
            T, ticks = self._mailbox
            self._mailbox = None
            try:
                target = self.model.ik(T, self._q_int)
            except (Unreachable, ValueError) as exc:
                self.refused += 1
                self.last_refusal = str(exc)
            else:
                self._q_ext = target.tolist()
                self.time_count = ticks
        if self.time_count > 1:  # plan_joint_cmd(): the next way-point
            n = self.time_count
            self._q_int = [qi + (qe - qi) / n for qi, qe in zip(self._q_int, self._q_ext)]
        else:
            self._q_int = list(self._q_ext)
        if self.time_count > 0:
            self.time_count -= 1
        self._next_ramp(self.t_ns + self.half_ns)

    def _next_ramp(self, t0_ns: int) -> None:
        """The servo agent's send half a tick after the tick: the next ramp (speed-clipped)."""
        last = self._ramps[-1]
        dt = t0_ns - last.t0_ns
        p00, p01, p10, p11 = self._phi(dt)
        e = [p00 * a + p01 * b for a, b in zip(last.e, last.ed)]
        ed = [p10 * a + p11 * b for a, b in zip(last.e, last.ed)]
        x = dt / 1e9
        r_end = [r + v * x for r, v in zip(last.r0, last.v)]
        # np.clip(q_int - sent, -lim, lim), value for value (also for NaN and signed zeros)
        self._sent = sent = [s + min(max(qi - s, -lim), lim)
                             for s, qi, lim in zip(self._sent, self._q_int, self._lim_deg)]
        period = self.period_s
        v_new = [(s - r) / period for s, r in zip(sent, r_end)]
        self._ramps.append(_Ramp(t0_ns, r_end, v_new, e, [d - (vn - vl) for d, vn, vl in zip(ed, v_new, last.v)]))
