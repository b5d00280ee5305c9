"""The Fanuc S400's arm behind its controller: joint loops, gravity, inertia, friction, saturation (issue 13).

Thesis §2.4, §4.2: the GMF1 is driven by its own controller; DROID sends it
poses over the serial line, KAREL interpolates a joint trajectory
(:class:`droid.sim.gmf1.controller.Motion`), and the controller's servos make
the arm follow it.  This module is that last part -- the arm as it follows
the interpolated path -- built from the robot file's ``[dynamics]`` and
``[axis_servo]`` tables (droid/kinematics/robots/fanuc_s400.toml, every value
sourced there).

The model (a justified simplification of the Reis's plant twin,
:mod:`droid.sim.reis.plant`):

* **Rigid-body dynamics** (:class:`droid.arm.rigid_body.RigidBody`, the same builder from
  the D-H table and ``[dynamics]``; Pinocchio in lockstep trials, the compiled kernel in
  droid-sim's world): the joint-space
  mass matrix ``M(q)`` plus the reflected rotor inertias ``J_r N^2``, and the
  gravity torques ``g(q)`` less the joint-2 balancer.  Coupling between the
  joints is kept (``qdd = (M + J_r N^2)^-1 (tau - g - friction)``); Coriolis
  and centrifugal torques are left out: the holder moves at a few mm/s to
  300 mm/s and their share is below 1 % of the gravity torques there.  ``M``
  and ``g`` are evaluated every :data:`MODEL_PERIOD_S` (the pose changes by
  well under a degree in that time), not every servo step -- the cost of a
  lockstep trial.
* **The controller's joint loops** (``[axis_servo]``): per joint a position
  loop on the motor-side encoder angle, ``w_cmd = ff w_ref + kp (q_ref - q_m)``,
  limited to the joint's ``vmax_deg_s`` (the rate limit), and a PI velocity
  loop ``tau = J_jj w_v (e + integral(e) / Ti)`` with ``J_jj`` the diagonal
  of the current inertia (the controller's own inertia setting), at
  ``servo_rate_hz``.
* **The amplifiers**: the motor torque saturates at ``k_t I_max`` and fades to
  0 at the back-EMF limit (``motor_no_load_speed_rad_s``); the integral stops
  while saturated (anti-windup).
* **Friction** on the motor side: Coulomb (smoothed over
  :data:`COULOMB_SMOOTH_RAD_S` of motor speed) plus viscous, through the gear.
* **Compliance** of the reducers, static: the motor-side encoders read
  ``q_m = q + tau / K`` (the link angle plus the drive's twist under the
  torque it carries); the resonance of ``K`` against the link inertia lies far
  above the loops' bandwidth, so it is not integrated.

The neutral arm's (:mod:`droid.arm`): the GMF1's KAREL twin (droid.sim.gmf1.controller) and the
ABB's EGM controller twin (droid.sim.abb.controller) both drive their arm through it, each from
its own robot file.

Gravity acts along -z of the robot's BASE frame (the controller's model has
no base transform; the GMF1 stands upright in every cell).  Angles here are
radians internally; the interface is degrees like the controller's.
"""
from __future__ import annotations

import math

import numpy as np

from droid.kinematics import RobotModel
from droid.arm.rigid_body import world_backend  # noqa: F401 - the arm twins' devices choose with it

#: The mass matrix and gravity are re-evaluated this often [s].
MODEL_PERIOD_S = 0.01
#: Coulomb friction is smoothed (tanh) over this motor speed [rad/s] (stable explicit steps).
COULOMB_SMOOTH_RAD_S = 2.0
#: The arm counts as at rest (integration skipped) when every joint is this close to a
#: constant reference [rad] and this slow [rad/s].
REST_POS_RAD = 1e-9
REST_VEL_RAD_S = 1e-8


class ArmDynamics:
    """The arm following its controller's reference; see the module docstring.

    ``advance(t_s, q_ref_deg)`` runs the servo steps up to ``t_s`` with the
    reference held at ``q_ref_deg`` over the interval (the reference a
    trajectory gives at the interval's end -- the caller advances in steps of
    the world's rate, KAREL's interpolation is far slower).  Read
    :attr:`q_deg` (the links: the truth) and :attr:`q_motor_deg` (the motor
    side, what the encoder cards count, in joint degrees).  ``rigid_body``: the
    :class:`droid.arm.rigid_body.RigidBody` backend, ``"pinocchio"`` (the default: lockstep
    trials) or ``"kernel"`` (droid-sim's world: no Pinocchio import).
    """

    def __init__(self, model: RobotModel, q0_deg, rigid_body: str = "pinocchio") -> None:
        from droid.arm.rigid_body import RigidBody  # a simulator's module (kinematics imports none)

        dyn, sv = model.dynamics, model.axis_servo
        if dyn is None or sv is None:
            raise ValueError(f"robot {model.name}: the arm twin needs [dynamics] and [axis_servo] tables")
        self.body = RigidBody(model.dh, dyn, backend=rigid_body)
        self.N = np.asarray(model.gearing.reduction, float)
        self.J_rotor = np.asarray(dyn.rotor_inertia_kgm2, float) * self.N ** 2
        self.tau_max = np.asarray(dyn.torque_constant_nm_per_a * dyn.amp_current_limit_a, float) * self.N
        self.w0_motor = np.asarray(dyn.motor_no_load_speed_rad_s, float)
        self.coulomb = np.asarray(dyn.coulomb_friction_nm, float) * self.N
        self.viscous = np.asarray(dyn.viscous_friction_nm_s_per_rad, float) * self.N ** 2
        self.K = np.asarray(dyn.hd_stiffness_nm_per_rad, float)
        self.balancer = float(dyn.balancer_moment_nm)
        self.kp = np.asarray(sv.position_gain_per_s, float)
        self.wv = 2.0 * math.pi * np.asarray(sv.velocity_bandwidth_hz, float)
        self.ti = np.asarray(sv.velocity_integral_time_s, float)
        self.ff = np.asarray(sv.velocity_feedforward, float)
        self.dt = 1.0 / sv.servo_rate_hz
        self.vmax = np.radians(np.asarray(model.vmax_deg_s, float))
        self._inv_K = 1.0 / self.K
        self._inv_ti = 1.0 / self.ti
        self._N_over_w0 = self.N / self.w0_motor
        self._N_over_smooth = self.N / COULOMB_SMOOTH_RAD_S
        self.q = np.radians(np.asarray(q0_deg, float)).copy()
        self.qd = np.zeros(6)
        self.integ = np.zeros(6)  # velocity-loop integral [rad/s]
        self.t_s = 0.0
        self._t_model = -math.inf
        self._q_ref_prev: np.ndarray | None = None
        self._rest_ref = None  # the reference [deg] the arm came to rest on (None: not at rest)
        self._update_model()
        # at power-up the arm stands on its reference with the integral holding gravity
        self.tau = self.g.copy()
        self.integ = self.tau / (self.Jdiag * self.wv) * self.ti
        self.steps = 0
        self.saturated_steps = 0

    def _update_model(self) -> None:
        M = self.body.mass(self.q) + np.diag(self.J_rotor)
        self.Minv = np.linalg.inv(M)
        self.Jdiag = np.diag(M).copy()
        self._Jwv = self.Jdiag * self.wv  # the velocity loop's gain [N m s/rad]
        g = self.body.gravity(self.q)
        g[1] -= -self.balancer * math.sin(self.q[1])  # the balancer carries part of joint 2's load
        self.g = g
        self._t_model = self.t_s

    @property
    def q_deg(self) -> np.ndarray:
        return np.degrees(self.q)

    @property
    def q_motor_deg(self) -> np.ndarray:
        """The motor-side angles in joint degrees: the links plus the reducers' twist."""
        return np.degrees(self.q + self.tau / self.K)

    def at_rest(self, q_ref_rad: np.ndarray) -> bool:
        return (self._q_ref_prev is not None and np.array_equal(q_ref_rad, self._q_ref_prev)
                and float(np.max(np.abs(self.qd))) < REST_VEL_RAD_S
                and float(np.max(np.abs(q_ref_rad - (self.q + self.tau / self.K)))) < REST_POS_RAD)

    def resting_on(self, q_ref_deg) -> bool:
        """At rest on this very reference object (:meth:`advance`'s first test, by identity): an
        advance toward it would only move the clock."""
        return self._rest_ref is not None and q_ref_deg is self._rest_ref

    def advance(self, t_s: float, q_ref_deg) -> bool:
        """Servo steps up to ``t_s`` [s] toward ``q_ref_deg``; True when the arm moved."""
        if self._rest_ref is not None and (q_ref_deg is self._rest_ref or np.array_equal(q_ref_deg, self._rest_ref)):
            self.t_s = t_s  # at rest on an unchanged reference: nothing moves (a cheap lockstep)
            return False
        self._rest_ref = None
        q_ref = np.radians(np.asarray(q_ref_deg, float))
        if self.at_rest(q_ref):
            self._rest_ref = q_ref_deg
            self.t_s = t_s
            return False
        prev = self._q_ref_prev if self._q_ref_prev is not None else q_ref
        n = max(0, int(math.floor((t_s - self.t_s) / self.dt + 1e-9)))
        if n == 0:
            return False
        w_ref = (q_ref - prev) / (n * self.dt)  # the reference's rate over the interval
        for _ in range(n):
            self._step(q_ref, w_ref)
        self.t_s += n * self.dt
        self._q_ref_prev = q_ref
        return True

    def _step(self, q_ref: np.ndarray, w_ref: np.ndarray) -> None:
        """One servo period (plain ufuncs on 6-vectors: np.clip is slow on small arrays)."""
        dt = self.dt
        if self.t_s + 1e-12 >= self._t_model + MODEL_PERIOD_S:
            self._update_model()
        qd = self.qd
        q_m = self.q + self.tau * self._inv_K  # what the motor encoders read
        w_cmd = self.ff * w_ref + self.kp * (q_ref - q_m)
        w_cmd = np.maximum(np.minimum(w_cmd, self.vmax), -self.vmax)  # the rate limit
        e = w_cmd - qd
        tau_cmd = self._Jwv * (e + self.integ * self._inv_ti)
        limit = self.tau_max * np.maximum(1.0 - np.abs(qd) * self._N_over_w0, 0.0)  # back-EMF
        tau = np.maximum(np.minimum(tau_cmd, limit), -limit)
        free = tau == tau_cmd
        if free.all():
            self.integ = self.integ + e * dt
        else:  # anti-windup: no integration on a saturated joint
            self.integ = np.where(free, self.integ + e * dt, self.integ)
            self.saturated_steps += 1
        friction = self.coulomb * np.tanh(qd * self._N_over_smooth) + self.viscous * qd
        self.qd = qd = qd + (self.Minv @ (tau - self.g - friction)) * dt
        self.q = self.q + qd * dt
        self.tau = tau
        self.steps += 1
