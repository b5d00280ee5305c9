"""The simulated Reis Robotstar V15: VME register map + arm dynamics from its robot file.

Thesis §2.3 and §4.1.2 describe the hardware this twin reproduces: six DC
servo motors through 100:1 harmonic drives, each behind a servo amplifier fed
by a signed 12-bit DAC (+-5 V), a 16-bit quadrature encoder counter per motor
(4000 counts per motor revolution, arbitrary value at power-up), a limit
switch per joint at a known position, two watchdog timers that disable the
amplifiers when they are not rewritten in time (a latched fault, cleared only
by a power cycle), and a passive pneumatic balancer on link 2.

Every physical value comes from the arm's robot file (``[dynamics]``,
``[gearing]``, ``[home]``, ``[limits]``; droid.kinematics.dynamics), the same
file the servo and the planner read.  Model (SI units; motor angles ``theta``
[rad] on the motor side, link angles ``q`` [rad]; ``p = A theta`` is the motor
position seen at the joint, ``A`` = the gearing with its 1 % coupling,
``q_deg = M^-1 counts``)::

    motors:  J_m dw/dt = tau_amp - A^T tau_s - b w - tau_c sign(w)       (stiction: stays at rest)
    drives:  tau_s = K (p - q) + D (dp/dt - dq/dt)                       (harmonic-drive compliance)
    links:   q'' = ABA(q, q', tau_s + tau_bal(q))                        (RigidBody: M(q), C, g)
    tau_amp = clip(dac/2048 * 5 V * k_a * k_t, +- i_max k_t)            (0 when the amps are off)
              limited to [-1 - w/w0, 1 - w/w0] i_max k_t                 (back-EMF: no torque at w0)
    tau_bal = -balancer_moment_nm * sin(q2)                              (link-2 pneumatic balancer)

integrated in one step per :meth:`advance` (``integrator="exact"``, the default): the
motor/drive/link system linearised at the current mass matrix, ``x' = F x + G [tau_motor;
tau_link]``, discretised exactly (matrix exponential, refreshed when a joint moved
``relinearise_deg``), with the nonlinear torques -- gravity, Coriolis, balancer (Pinocchio
``nonLinearEffects`` at the step's start), amplifier saturation and back-EMF, Coulomb friction
with stiction (Karnopp: a motor at rest stays at rest while the friction needed to hold it is
below ``coulomb_friction_nm``) -- held over the step (zero-order hold, as the DACs hold the
amplifier command between servo ticks).  The fastest mode of the linear part is ~115 Hz
(the drives against the rotors), so the exact discretisation is what makes a 2 ms step
possible: semi-implicit Euler needs ~0.1 ms substeps to converge on it.  The reference
(``integrator="substep"``) is semi-implicit Euler with Pinocchio's ABA at every ``substep_s``;
:data:`EXACT_BOUND_DEG` states how close the two are (a test measures it).  Near
a mechanical stop or with a jammed motor the substep integrator takes over.  The
encoders count the motors (motor side, as on the real arm); the limit switches
and the mechanical stops see the links.  With ``compliance=False`` the drives
are rigid (q = p) and ``(M(q) + A^-T J_m A^-1) q'' = A^-T tau_motor - C - g +
tau_bal`` is integrated instead: the servo-logic tests use it so that encoder
counts and joint angles agree exactly (droid-sim's world runs it too, the cell's
default): where the compiled kernel is in use (droid.kernel) its substeps run there, one call
an advance (``rigid_steps``, :meth:`ReisPlant._steps_rigid_compiled`), bit for bit those of
:meth:`ReisPlant._steps_rigid`, which stays the reference and takes the advances near a hard
stop or with a jammed motor.  When the amplifiers are off a holding
brake adds ``brake_torque_nm`` of friction.

The world is not the model (issue 13): ``home_error_deg`` moves the true
switches from the robot file's positions, ``dh_error`` makes the true link
lengths/twists differ; the controller knows neither.

Register traffic per :meth:`ReisPlant.advance`: DACs and watchdog registers are
read at the start, encoders, limit switches and AMP_STATUS written at the end
(layout: :mod:`droid.subunits.reis.vme_map`).  Everything is seeded and
deterministic.

``M(q)``, ``C qd + g`` and the forward dynamics come from
:class:`droid.arm.rigid_body.RigidBody`: Pinocchio's by default (lockstep trials), the
compiled kernel's in droid-sim's world (``rigid_body="kernel"``, so that the real-time
simulator does not import Pinocchio); this module imports neither itself.
"""
from __future__ import annotations

import functools
import math
import struct
from dataclasses import dataclass

import numpy as np

from droid import kernel as _kernel_switch
from droid.kinematics import load_robot
from droid.arm.rigid_body import DhError, KernelRigidBody, RigidBody
from droid.subunits.reis import vme_map as vm

Six = tuple[float, float, float, float, float, float]
INTEGRATORS = ("exact", "substep")
#: Tested bound [deg per joint] of the "exact" integrator against the converged "substep"
#: reference (10 kHz) over a 1 s servo move of all six joints (tests/reis/test_plant_dynamics.py;
#: measured 0.0035 deg, the reference's own 2 kHz default differs by 0.0105 deg).
EXACT_BOUND_DEG = 0.01
MAX_JOINT_SPEED_DEG_PER_S = 360.0  # bound used to skip hard-stop checks far from the stops
ZERO6: Six = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
# one copy of pre-packed bytes per register block (vm.store's rule: never struct.pack_into on a shared map)
_ENCODERS, _DACS, _U16 = struct.Struct(vm.ENCODERS_FORMAT), struct.Struct(vm.DACS_FORMAT), struct.Struct(vm.U16_FORMAT)
# the two watchdog registers are adjacent u16s: one unpack reads both
_WATCHDOGS = struct.Struct("<2H")
assert vm.WATCHDOG_OFFSETS[1] == vm.WATCHDOG_OFFSETS[0] + 2 and vm.U16_FORMAT == "<H"
# numpy.linalg.solve's own kernel (LAPACK gesv, one right-hand side) without its per-call checks and
# error-state context (~10 us of 20 at the rigid integrator's two solves a millisecond): the same
# routine on the same arrays, the same bits; the rigid arm's mass matrix is never singular
def _gesv():
    """numpy's private kernel if this numpy has it and it answers as ``np.linalg.solve`` does on
    a check system (bit for bit), else the public ``np.linalg.solve``."""
    try:
        from numpy.linalg import _umath_linalg

        fast = functools.partial(_umath_linalg.solve1, signature="dd->d")
        a, b = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.25], [0.5, 0.25, 2.0]]), np.array([1.0, -2.0, 0.7])
        if fast(a, b).tobytes() == np.linalg.solve(a, b).tobytes():
            return fast
    except Exception:  # noqa: BLE001 - another numpy: any failure means the public solve  # pragma: no cover
        pass
    return np.linalg.solve  # pragma: no cover


_solve = _gesv()
# AMP_STATUS's two bytes by (amps on, watchdog fault)
_AMP_STATUS = {(on, fault): _U16.pack((vm.AMP_STATUS_POWERED if on else 0) | (vm.AMP_STATUS_WATCHDOG_FAULT if fault else 0))
               for on in (False, True) for fault in (False, True)}


@functools.lru_cache(maxsize=32)
def _robot(robot: str):
    model = load_robot(robot)
    if model.dynamics is None:
        raise ValueError(f"{model.source}: [dynamics]: missing (the plant twin needs the arm's dynamics)")
    if model.dh is None:
        raise ValueError(f"{model.source}: [dh]: missing (the plant twin builds its rigid-body model from it)")
    return model


@dataclass(frozen=True)
class ReisPlantParams:
    """The simulated arm: which robot file, how the world differs from it, integration settings."""

    robot: str = "reis_v15"  # bundled robot name or .toml path: the single source of the arm's data
    substep_s: float = 0.0005  # integration step (2 kHz)
    compliance: bool = True  # harmonic-drive stiffness between motor and link (False: rigid drives)
    # "exact" (the default): one zero-order-hold step of the linearised motor/drive/link system
    # per advance -- the linear part (motors, drive springs and dampers, links at M(q)) exact,
    # M(q) refreshed when a joint moved relinearise_deg; gravity, Coriolis, the balancer, Coulomb
    # friction (Karnopp), saturation and back-EMF held over the step.  Measured against the
    # "substep" integration at 10-20 kHz (converged: the two agree within 0.0023 deg) on a 1 s
    # servo move of every joint: within 0.0035 deg per joint (EXACT_BOUND_DEG is the tested
    # bound), closer than "substep" at its 2 kHz default (0.0105 deg), at ~1/3 of its cost.
    # "substep": semi-implicit Euler of the nonlinear equations at every substep_s (Pinocchio's
    # ABA each substep) -- the reference; converges as substep_s shrinks.  Near a mechanical
    # stop or with a jammed motor "exact" hands the advance to it.
    integrator: str = "exact"
    relinearise_deg: float = 0.5  # "exact": recompute M(q)^-1 and the step's matrices after this joint motion
    balancer: bool = True  # the link-2 pneumatic balancer
    home_error_deg: Six = ZERO6  # true switch position minus the robot file's [deg]
    dh_error: DhError = DhError()  # true link lengths/twists minus the robot file's
    watchdog_timeout_s: float = 0.100  # a watchdog register unchanged this long latches amps off
    initial_joint_deg: Six = ZERO6  # pose at power-up (centre)
    initial_spread_deg: float = 15.0  # power-up pose = centre + seeded uniform +-spread

    def __post_init__(self) -> None:
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"unknown integrator {self.integrator!r} (known: {', '.join(INTEGRATORS)})")

    @property
    def model(self):
        """The robot file's model (kinematics, gearing, limits, home, dynamics)."""
        return _robot(self.robot)

    @property
    def joint_to_counts(self) -> tuple[tuple[float, ...], ...]:
        """M [motor counts per joint degree], counts = M @ q_deg (gearing + coupling)."""
        return tuple(tuple(float(x) for x in row) for row in self.model.gearing.joint_to_counts_matrix)

    @property
    def switch_joint_deg(self) -> Six:
        """True home-switch positions [deg]: the robot file's plus ``home_error_deg``."""
        return tuple(float(a + b) for a, b in zip(self.model.home_switch_deg, self.home_error_deg))

    @property
    def switch_active_side(self) -> tuple[int, ...]:
        """+1: the switch (a cam) is active for q > switch; the robot file's search direction."""
        return tuple(int(x) for x in self.model.home_search_dir)

    @property
    def hard_stop_min_deg(self) -> Six:
        return tuple(float(x) - self.model.dynamics.hard_stop_margin_deg for x in self.model.joint_min_deg)

    @property
    def hard_stop_max_deg(self) -> Six:
        return tuple(float(x) + self.model.dynamics.hard_stop_margin_deg for x in self.model.joint_max_deg)


def expm(m: np.ndarray) -> np.ndarray:
    """Matrix exponential (scaling and squaring, 18-term Taylor); numpy only.  Also the fast
    arm model's per-joint transition (droid.sim.reis.fast_arm)."""
    norm = np.max(np.sum(np.abs(m), axis=1))
    k = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0.5 else 0
    a = m / (2.0 ** k)
    out = np.eye(len(m))
    term = np.eye(len(m))
    for i in range(1, 19):
        term = term @ a / i
        out = out + term
    for _ in range(k):
        out = out @ out
    return out


def _zoh(fg: tuple[np.ndarray, np.ndarray], dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation: (Phi, Gamma) of x' = F x + G u over dt."""
    F, G = fg
    n, m = G.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = F * dt
    aug[:n, n:] = G * dt
    e = expm(aug)
    return e[:n, :n].copy(), e[:n, n:].copy()


class ReisPlant:
    """The robot behind the VME register map.  ``regs`` is the map's bytes.

    ``regs`` may be supplied (e.g. an mmap of a POSIX shared-memory object,
    :mod:`droid.sim.reis.vme_shm`); by default it is a private bytearray.
    ``encoder_power_up_counts`` and ``initial_joint_deg`` override the seeded
    power-up values (tests).  ``rigid_body``: the links' rigid-body dynamics
    (:class:`droid.arm.rigid_body.RigidBody`'s backend): ``"pinocchio"`` (the
    default; lockstep trials, whose published results it reproduces bit for bit) or
    ``"kernel"`` (the compiled RNEA/CRBA, no Pinocchio import: droid-sim's world).
    """

    def __init__(
        self,
        params: ReisPlantParams | None = None,
        seed: int = 0,
        *,
        regs=None,
        encoder_power_up_counts=None,
        initial_joint_deg=None,
        kernel: str | None = None,
        rigid_body: str = "pinocchio",
    ):
        p = self.params = params if params is not None else ReisPlantParams()
        #: the compiled kernel (droid._kernel) or None for the Python reference: DROID_KERNEL
        #: (droid.kernel) unless ``kernel`` ("c" or "python") says otherwise (tests, benches)
        self._k = (_kernel_switch.compiled() if kernel is None else
                   _kernel_switch.load_compiled() if kernel == "c" else None)
        if kernel not in (None, "c", "python"):
            raise ValueError(f"kernel {kernel!r}: 'c', 'python' or None (DROID_KERNEL)")
        self._rng = np.random.default_rng(seed)
        self._attach_registers(regs)
        self._drive_constants(p, rigid_body)
        self._limit_constants(p)
        self._rigid_constants(p)
        self._F0, self._G0 = self._system_matrices(np.zeros((6, 6)))  # the M(q)-free blocks
        self._initial_state(p, initial_joint_deg)
        self.time_s = 0.0
        #: contact with the world (droid.sim.contact.ToolContact, or None): asked at each advance's
        #: start for the joint torques J^T F of the environment's force on the tool, held over the
        #: step; None (the default) or a None answer leaves the step exactly as without contact
        self.contact = None
        self._power_up(encoder_power_up_counts)

    def _attach_registers(self, regs) -> None:
        """The VME register map's bytes (``regs``, or a private bytearray), zeroed."""
        self.regs = regs if regs is not None else bytearray(vm.MAP_SIZE)
        self._view = memoryview(self.regs).cast("B")
        if self._view.nbytes < vm.MAP_SIZE:
            raise ValueError(f"register buffer has {self._view.nbytes} bytes, need {vm.MAP_SIZE}")
        self._view[: vm.MAP_SIZE] = bytes(vm.MAP_SIZE)

    def _drive_constants(self, p: ReisPlantParams, rigid_body: str = "pinocchio") -> None:
        """The drive train from the robot file: gearing and coupling (motor -> link), the links'
        rigid body (with the DH errors), the harmonic drives' stiffness and damping, the motors'
        torque limits and friction."""
        robot = p.model
        dyn = self.dynamics = robot.dynamics
        m = robot.gearing.joint_to_counts_matrix
        self._m = m  # counts per deg
        self._minv = np.linalg.inv(m)  # deg per count
        self._counts_per_rad = robot.gearing.encoder_counts_per_rev / (2.0 * math.pi)  # (6,)
        self.true_dh = p.dh_error.apply(robot.dh)
        self.body = RigidBody(self.true_dh, dyn, backend=rigid_body)
        a = math.radians(1.0) * self._counts_per_rad * self._minv  # p_rad = A @ theta_rad
        self._A = a
        self._AT = a.T.copy()
        self._Ainv = np.linalg.inv(a)
        self._AinvT = self._Ainv.T.copy()
        self._J_rotor_ref = self._AinvT @ np.diag(dyn.rotor_inertia_kgm2) @ self._Ainv  # at the joints
        kd = np.asarray(dyn.hd_stiffness_nm_per_rad, float)[:, None]
        dd = np.asarray(dyn.hd_damping_nm_s_per_rad, float)[:, None]
        # drive torques tau_s = S @ [theta, omega, q, qd]; their motor-side reaction A^T tau_s
        self._S = np.hstack((kd * a, dd * a, -np.diagflat(kd), -np.diagflat(dd)))
        self._ATS = a.T @ self._S
        self._Jm = np.asarray(dyn.rotor_inertia_kgm2, float)
        self._K = np.asarray(dyn.hd_stiffness_nm_per_rad, float)
        self._D = np.asarray(dyn.hd_damping_nm_s_per_rad, float)
        self._b = np.asarray(dyn.viscous_friction_nm_s_per_rad, float)
        self._tau_c = np.asarray(dyn.coulomb_friction_nm, float)
        self._tau_brake = np.asarray(dyn.brake_torque_nm, float)
        scale = dyn.dac_full_scale_v / (vm.DAC_MAX + 1)
        self._tau_per_dac = np.asarray(dyn.torque_per_volt_nm_per_v, float) * scale
        self._tau_max = np.asarray(dyn.motor_torque_limit_nm, float)
        self._w0 = np.asarray(dyn.motor_no_load_speed_rad_s, float)
        self._tau_max_w0 = self._tau_max / self._w0
        self._bal = dyn.balancer_moment_nm if p.balancer else 0.0

    def _limit_constants(self, p: ReisPlantParams) -> None:
        """The home switches and hard stops [rad], and the per-advance constants as plain floats."""
        self._sw = np.radians(np.asarray(p.switch_joint_deg, float))
        self._side = np.asarray(p.switch_active_side, float)
        self._stop_min = np.radians(np.asarray(p.hard_stop_min_deg, float))
        self._stop_max = np.radians(np.asarray(p.hard_stop_max_deg, float))
        self._zero6 = np.zeros(6)
        self._stop_mid = 0.5 * (self._stop_min + self._stop_max)
        self._stop_half = 0.5 * (self._stop_max - self._stop_min)
        self._stop_lim: dict = {}  # dt -> half range minus the margin of _near_stop
        self._stop_lim_arr: dict = {}  # the same as float64 arrays (the compiled kernel's exact_checks)
        self._bit_weights = np.array([1 << j for j in range(vm.N_JOINTS)], np.int64)
        # the same constants as plain floats: the per-advance work on six values is cheaper in
        # Python floats than in numpy calls (issue 13 item 6; the same IEEE operations, same bits)
        self._fl = {"tau_per_dac": self._tau_per_dac.tolist(), "tau_max": self._tau_max.tolist(),
                    "tau_max_w0": self._tau_max_w0.tolist(), "cpr": np.broadcast_to(self._counts_per_rad, 6).tolist(),
                    "sw": self._sw.tolist(), "side": self._side.tolist(), "stop_mid": self._stop_mid.tolist()}
        # per joint, for the fused DAC -> torque loop of advance: (torque per DAC count, limit, limit / w0)
        self._drive_consts = list(zip(self._fl["tau_per_dac"], self._fl["tau_max"], self._fl["tau_max_w0"]))
        self._q_list: tuple = (None, None)  # (the array self._q, its tolist()): q is read as floats 3x per step
        self._z = np.empty(36)  # the exact step's input [x; tau_motor; tau_link] (filled in place)
        self._n_substeps: dict = {}  # dt_s -> substeps per advance (validated once)
        self._tau_c_list = self._tau_c.tolist()
        # the compiled kernel's constants, one float64 vector (droid/_kernel.c: C_TAU_PER_DAC ..)
        self._consts = np.concatenate([np.broadcast_to(np.asarray(v, float), 6) for v in (
            self._tau_per_dac, self._tau_max, self._tau_max_w0, self._tau_c, self._tau_brake, self._counts_per_rad,
            self._sw, self._side)] + [np.array([self._bal], float)])

    def _rigid_constants(self, p: ReisPlantParams) -> None:
        """The compiled rigid-drive substeps (droid/_kernel.c ``rigid_steps``; rigid drives only):
        whether they run here, their constants (A, A^-T, A^-1, the rotors at the joints, viscous
        friction, no-load speeds: one float64 vector) and the body they ask for M(q) and C qd + g."""
        k = self._k
        self._k_rigid = k if not p.compliance and _kernel_switch.rigid_ready(k) else None
        self._rigid_consts = np.concatenate([np.ascontiguousarray(v, float).ravel() for v in (
            self._A, self._AinvT, self._Ainv, self._J_rotor_ref, self._b, self._w0)])
        assert k is None or not hasattr(k, "R_LEN") or self._rigid_consts.size == k.R_LEN
        body = self.body
        # the kernel's own RNEA and CRBA on the body's packed model, or the body's methods (Pinocchio)
        self._rigid_body = ((body._buf, None, None) if type(body) is KernelRigidBody else
                            (None, body.mass, body.nle))
        self._qbuf, self._qdbuf = np.empty(6), np.empty(6)  # q and qd for the body's methods

    def _initial_state(self, p: ReisPlantParams, initial_joint_deg) -> None:
        """The power-up pose (seeded spread about ``initial_joint_deg``), at rest against gravity;
        the integrator's state."""
        if initial_joint_deg is None:
            spread = self._rng.uniform(-p.initial_spread_deg, p.initial_spread_deg, vm.N_JOINTS)
            initial_joint_deg = np.asarray(p.initial_joint_deg, float) + spread
        q0 = np.radians(np.asarray(initial_joint_deg, float))
        self._q = q0.copy()  # link angles [rad]
        self._qd = np.zeros(6)  # link speeds [rad/s]
        # the motors start where the drives hold the links still against gravity (no jump at power-up)
        p0 = q0 + (self._static_load(q0) / self._K if p.compliance else 0.0)
        self._theta = self._Ainv @ p0  # motor angles [rad], 0 at the undeflected home pose
        self._omega = np.zeros(6)  # motor speeds [rad/s]
        if not p.compliance:
            self._q = self._A @ self._theta
        self._jammed = np.zeros(6, bool)
        self._any_jammed = False
        self._exact = p.compliance and p.integrator == "exact"
        self._lin_q = None  # q [rad] of the current linearisation (exact integrator)
        self._relin_rad = math.radians(p.relinearise_deg)
        self._disc: dict = {}  # dt -> (Phi, Gamma) at that linearisation
        self._rest: tuple | None = None  # the key (_rest_key) of the last advance if it changed nothing
        self._rest_out: tuple | None = None  # (encoder offsets, encoders, their bytes, switch bytes) at that rest
        self.rest_steps = 0  # advances that found the arm at rest with unchanged inputs (not integrated)

    def _static_load(self, q_rad) -> np.ndarray:
        """Joint torques [N m] the drives carry to hold the links at rest: gravity minus the balancer."""
        g = self.body.gravity(q_rad)
        g[1] -= self._balancer(q_rad)
        return g

    def _balancer(self, q_rad) -> float:
        return -self._bal * math.sin(q_rad[1])

    # -- power ---------------------------------------------------------------
    def _power_up(self, encoder_counts=None) -> None:
        if encoder_counts is None:
            encoder_counts = self._rng.integers(0, vm.ENCODER_MODULUS, vm.N_JOINTS)
        counts = self._floor_counts()
        self._enc_offset = np.array([(int(e) - c) % vm.ENCODER_MODULUS for e, c in zip(encoder_counts, counts)],
                                    np.int64)
        self._enc_offset_list = self._enc_offset.tolist()
        # The amplifiers come up off; the first write of both watchdog registers
        # arms the timers and powers them (a watchdog that is not running yet
        # cannot have expired).  From then on a register not rewritten within
        # the timeout latches them off until power_cycle().
        self._amps_on = False
        self._wd_armed = [False, False]
        self._wd_fault = False
        self._wd_age_s = [0.0, 0.0]
        vm.store(self._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *([0] * vm.N_JOINTS))
        self._wd_last = [struct.unpack_from(vm.U16_FORMAT, self._view, o)[0] for o in vm.WATCHDOG_OFFSETS]
        self._write_outputs()

    def power_cycle(self) -> None:
        """Switch the controller off and on: clears the watchdog latch, DACs to 0,
        encoder counters to new arbitrary values (homing is lost); the arm stays put."""
        self._omega = np.zeros(6)
        self._qd = np.zeros(6) if not self.params.compliance else self._qd
        self._power_up()

    @property
    def amps_on(self) -> bool:
        """True while the servo amplifiers are powered (no watchdog latch)."""
        return self._amps_on

    # -- state -------------------------------------------------------------------
    def _floor_counts(self) -> list[int]:
        cpr = self._counts_per_rad
        return [math.floor(th * c) for th, c in zip(self._theta, cpr)]

    # Alike in shape only to Dynamics' derived properties: the plant's state in counts.
    @property
    def motor_counts(self) -> np.ndarray:
        """True motor positions [counts, float], 0 at the undeflected home pose."""
        return self._theta * self._counts_per_rad

    @property
    def motor_speed_counts_per_s(self) -> np.ndarray:
        """Motor speeds [counts/s]."""
        return self._omega * self._counts_per_rad

    @property
    def joint_deg(self) -> np.ndarray:
        """True link angles [deg] (the motor side plus the drives' deflection)."""
        return np.degrees(self._q)

    @property
    def motor_joint_deg(self) -> np.ndarray:
        """The joint angles the motor encoders imply [deg] (q = M^-1 m; no deflection)."""
        return self._minv @ self.motor_counts

    @property
    def limit_switches(self) -> tuple[bool, ...]:
        """Limit switch states, joint 1 first (cams on the links: active on the ``switch_active_side``)."""
        return tuple(bool(x) for x in self._side * (self._q - self._sw) > 0.0)

    @property
    def encoder_raw(self) -> tuple[int, ...]:
        """The six 16-bit counter values as the hardware shows them [counts]."""
        c = np.floor(self._theta * self._counts_per_rad).astype(np.int64)
        return tuple(((c + self._enc_offset) % vm.ENCODER_MODULUS).tolist())

    def wcp_true(self) -> np.ndarray:
        """The true wrist-centre pose (4x4, mm, robot base frame) of the true arm (with ``dh_error``)."""
        return self.body.wcp_mm(self.joint_deg)

    def jam(self, joint: int, jammed: bool = True) -> None:
        """Fault injection: block motor ``joint`` (0-based) mechanically, or release it."""
        self._jammed[joint] = bool(jammed)
        self._any_jammed = bool(self._jammed.any())
        if jammed:
            self._omega[joint] = 0.0

    # -- simulation -------------------------------------------------------------
    def gravity_joint_torque_nm(self, q_deg) -> np.ndarray:
        """Net static joint torques [N m] gravity exerts at ``q_deg`` after the balancer
        (positive: gravity drives the joint positive)."""
        return -self._static_load(np.radians(np.asarray(q_deg, float)))

    def advance(self, dt_s: float) -> None:
        """Read DACs/watchdogs from ``regs``, integrate ``dt_s`` (a whole number of
        substeps), write encoders, limit switches and AMP_STATUS."""
        p = self.params
        n = self._n_substeps.get(dt_s)
        if n is None:
            n = int(round(dt_s / p.substep_s))
            if n < 1 or abs(n * p.substep_s - dt_s) > 1e-9:
                raise ValueError(f"advance({dt_s}) is not a whole number of {p.substep_s} s substeps")
            self._n_substeps[dt_s] = n
        self._read_inputs(dt_s)
        ext = None if self.contact is None else self.contact.joint_torque(self.body, self._q, self._qd, dt_s)
        if self._exact and self._k is not None and not self._any_jammed:
            # the exact integrator keeps no rest key (below): its compiled step in one call, as
            # _integrate makes it once its stop limits and linearisation exist (issue 44)
            dt = n * p.substep_s
            lim, got = self._stop_lim_arr.get(dt), self._disc.get(dt)
            if lim is not None and got is not None and self._advance_exact_compiled(dt, got, ext, lim) is None:
                self.time_s += dt
                self._rest = self._rest_out = None
                return
        # An arm at rest whose inputs did not change: the last step computed exactly this one's
        # arguments and left the state bit for bit as it found it, so this one would too (the
        # integration is a pure function of what the key holds; the outputs are still written).
        # Rigid drives and the substep integrator only: the exact integrator's compliant links
        # never come to rest to the last bit (measured: no such step in 10 s of holding), so
        # there the key would be a cost without a use.
        key = None if ext is not None or self._any_jammed or self._exact else self._rest_key(n)
        if key is not None and key == self._rest:
            self.rest_steps += 1
            self.time_s += n * p.substep_s
            self._write_rest_outputs()
            return
        self._integrate(n, ext)
        # (the motor angles first: a moving arm is told by them without the whole key)
        self._rest = key if key is not None and self._theta.tobytes() == key[3] and key == self._rest_key(n) else None
        self._rest_out = None

    def _rest_key(self, n: int) -> tuple:
        """Everything an advance of ``n`` substeps reads besides the constant parameters (no
        contact force, no jammed motor): the state, the linearisation of the exact integrator,
        the amplifiers' power and, when powered, the DAC registers."""
        lin = self._lin_q
        return (n, self._amps_on, bytes(self._view[vm.DAC_OFFSET:vm.DAC_OFFSET + _DACS.size]) if self._amps_on else None,
                self._theta.tobytes(), self._omega.tobytes(), self._q.tobytes(), self._qd.tobytes(),
                None if lin is None else lin.tobytes())

    def _write_rest_outputs(self) -> None:
        """:meth:`_write_outputs` for an arm at rest: the encoder and switch registers' bytes are
        functions of the state (the rest key's) and the encoder offsets, so they are packed once
        per rest and offsets, then copied in each step (AMP_STATUS as ever)."""
        out, offsets = self._rest_out, self._enc_offset_list
        if out is None or out[0] != offsets:
            self._write_outputs()
            view = self._view
            self._rest_out = (list(offsets), self._enc_written,
                              bytes(view[vm.ENCODER_OFFSET:vm.ENCODER_OFFSET + _ENCODERS.size]),
                              bytes(view[vm.LIMIT_SWITCH_OFFSET:vm.LIMIT_SWITCH_OFFSET + 2]))
            return
        view = self._view
        self._enc_written = out[1]
        view[vm.ENCODER_OFFSET:vm.ENCODER_OFFSET + _ENCODERS.size] = out[2]
        view[vm.LIMIT_SWITCH_OFFSET:vm.LIMIT_SWITCH_OFFSET + 2] = out[3]
        view[vm.AMP_STATUS_OFFSET:vm.AMP_STATUS_OFFSET + 2] = _AMP_STATUS[(self._amps_on, self._wd_fault)]

    def _integrate(self, n: int, ext) -> None:
        """One advance of ``n`` substeps from the inputs just read (``ext``: the contact's joint
        torques or None): the state, ``time_s`` and the output registers."""
        p = self.params
        lo, hi = vm.DAC_MIN, vm.DAC_MAX
        h = p.substep_s
        if self._k_rigid is not None and not self._any_jammed and self._steps_rigid_compiled(n, h, ext):
            self.time_s += n * h
            return
        if self._k is not None and self._exact and not self._any_jammed:  # the compiled kernel's guards
            lim = self._stop_lim_arr.get(n * h)
            if lim is None:
                self._near_stop(n * h, self._q.tolist())  # fills _stop_lim
                lim = self._stop_lim_arr[n * h] = np.array(self._stop_lim[n * h])
            got = self._disc.get(n * h)
            if got is not None:  # the guards, nle and the step in one call (the same as below, issue 44)
                code = self._advance_exact_compiled(n * h, got, ext, lim)
                if code is None:
                    self.time_s += n * h
                    return
            else:
                code = self._k.exact_checks(self._q, self._lin_q, self._relin_rad, self._stop_mid, lim)
            if code != 2:
                self._step_exact_compiled(n * h, ext, relin=code == 1)
                self.time_s += n * h
                return
        cache = self._q_list
        ql = cache[1] if cache[0] is self._q else self._q.tolist()
        if self._exact and not (self._any_jammed or self._near_stop(n * h, ql)):
            if self._amps_on:
                # the DACs -> amplifier torques, clipped to +-tau_max, then to the back-EMF range at the
                # step's start speed, in one loop over plain floats (the same IEEE operations as the
                # min/max form of the substep branch below: max(a, b) is b if b > a else a)
                drive = []
                add = drive.append
                for d, (k, tm, a), w in zip(_DACS.unpack_from(self._view, vm.DAC_OFFSET), self._drive_consts,
                                            self._omega.tolist()):
                    d = d if d > lo else lo
                    v = float(d if d < hi else hi) * k
                    v = v if v > -tm else -tm
                    v = v if v < tm else tm
                    b = -tm - a * w
                    v = v if v > b else b
                    b = tm - a * w
                    add(v if v < b else b)
                tau_c = self._tau_c
            else:
                drive, tau_c = ZERO6, self._tau_c + self._tau_brake
            self._step_exact(n * h, drive, tau_c, ql, ext)
            self.time_s += n * h
            return
        if self._amps_on:
            fl = self._fl
            dacs = _DACS.unpack_from(self._view, vm.DAC_OFFSET)
            drive = [min(tm, max(-tm, float(min(hi, max(lo, d))) * k))
                     for d, k, tm in zip(dacs, fl["tau_per_dac"], fl["tau_max"])]
            tau_c = self._tau_c
        else:
            drive = ZERO6
            tau_c = self._tau_c + self._tau_brake
        if p.compliance:
            self._steps_compliant(n, h, np.array(drive), tau_c, ext)
        else:
            self._steps_rigid(n, h, np.array(drive), tau_c, ext)
        self.time_s += n * h
        self._write_outputs()

    def _steps_compliant(self, n: int, h: float, drive, tau_c, ext=None) -> None:
        """Semi-implicit Euler on the state s = [theta, omega, q, qd] (one 24-vector, few numpy
        calls per substep: the drive torques and their motor-side reaction are one matrix
        product each)."""
        S, ATS = self._S, self._ATS
        h_over_j = h / self._Jm
        damp = 1.0 / (1.0 + self._b * h_over_j)
        hjd = h_over_j * damp
        dw_c = tau_c * h_over_j
        neg_dw_c = -dw_c
        aba = self.body.aba
        st = np.concatenate((self._theta, self._omega, self._q, self._qd))
        theta, omega, q, qd = st[0:6], st[6:12], st[12:18], st[18:24]
        stops = bool(self._jammed.any()) or self._near_stop(n * h, self._q.tolist())
        bal, sin = self._bal, math.sin
        tmax, tmax_w0, two_tmax = self._tau_max, self._tau_max / self._w0, 2.0 * self._tau_max
        amps = self._amps_on
        for _ in range(n):
            ts = S @ st  # drive torques at the joints: K (A theta - q) + D (A omega - qd)
            if amps:  # back-EMF: the amplifier's torque range shifts with the motor speed
                hi = tmax - tmax_w0 * omega
                tau_m = np.minimum(np.maximum(drive, hi - two_tmax), hi)
            else:
                tau_m = drive
            w = omega * damp + hjd * (tau_m - ATS @ st)
            omega[:] = w - np.maximum(np.minimum(w, dw_c), neg_dw_c)  # Coulomb + stiction
            if bal:
                ts[1] -= bal * sin(q[1])
            if ext is not None:  # the environment's force on the tool, J^T F (held over the advance)
                ts += ext
            qd += h * aba(q, qd, ts)
            if stops:
                omega[:], qd[:] = self._apply_stops(q, omega, qd)
            theta += h * omega
            q += h * qd
        self._theta, self._omega, self._q, self._qd = theta.copy(), omega.copy(), q.copy(), qd.copy()

    # -- the exact (linearised, zero-order-hold) integrator --------------------------------
    def _discretise(self, dt: float, ql: list | None, relin: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(Phi, Gamma) at the current linearisation; ``ql``: ``self._q`` as floats.  ``relin``:
        whether to relinearise, when the caller has tested it (the compiled kernel; ``ql`` is then
        only needed if True), else None: tested here."""
        q = self._q
        lin, r = self._lin_q, self._relin_rad
        tested = relin is not None
        if not tested:
            relin = lin is None
        if not relin and not tested:
            for a, b in zip(ql, self._lin_list):
                if abs(a - b) > r:
                    relin = True
                    break
        if relin:
            self._lin_q = q.copy()
            self._lin_list = ql
            self._disc = {}
            self._minv_lin = self.body.minv(q)
        got = self._disc.get(dt)
        if got is None:
            minv = self._minv_lin
            F, G = self._F0.copy(), self._G0.copy()
            F[18:24] = minv @ self._S  # link accelerations from the drive torques: M^-1 (K (A theta - q) + D ..)
            G[18:24, 6:12] = minv
            phi, gam = _zoh((F, G), dt)
            g_m = gam[:, 0:6].copy()  # the state's response to a motor torque held over the step
            # one product per step: [Phi | Gamma] @ [x; tau_motor; tau_link]
            got = self._disc[dt] = (np.hstack((phi, gam)), g_m, np.diag(g_m[6:12]).tolist())
            assert got[0].shape == (24, 36)
        return got

    def _system_matrices(self, minv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """F (24x24) and G (24x12) of x = [theta, omega, q, qd], u = [tau_motor, tau_link]."""
        A, K, D = self._A, np.diag(self._K), np.diag(self._D)
        jinv = np.diag(1.0 / self._Jm)
        F = np.zeros((24, 24))
        G = np.zeros((24, 12))
        F[0:6, 6:12] = np.eye(6)
        F[6:12, 0:6] = -jinv @ A.T @ K @ A
        F[6:12, 6:12] = -jinv @ (np.diag(self._b) + A.T @ D @ A)
        F[6:12, 12:18] = jinv @ A.T @ K
        F[6:12, 18:24] = jinv @ A.T @ D
        F[12:18, 18:24] = np.eye(6)
        F[18:24, 0:6] = minv @ K @ A
        F[18:24, 6:12] = minv @ D @ A
        F[18:24, 12:18] = -minv @ K
        F[18:24, 18:24] = -minv @ D
        G[6:12, 0:6] = jinv
        G[18:24, 6:12] = minv
        return F, G

    def _step_exact(self, dt: float, drive, tau_c, ql: list, ext=None) -> None:
        """One zero-order-hold step of ``dt`` (see the module docstring and :data:`EXACT_BOUND_DEG`).
        ``drive``: the six motor torques [N m] after saturation and back-EMF; ``ql``: ``self._q``
        as floats.  Writes the step's outputs (encoders, switches, AMP_STATUS)."""
        pg, g_m, g_wd = self._discretise(dt, ql)
        omega, q, qd = self._omega, self._q, self._qd
        om = omega.tolist()
        tau_link = self.body.nle(q, qd)  # C qd + g (Pinocchio's buffer, or a new array)
        nl = -tau_link[1]
        if self._bal:
            nl -= self._bal * math.sin(ql[1])
        z = self._z  # [theta, omega, q, qd, drive, -tau_link], as np.concatenate would build it
        z[0:6] = self._theta
        z[6:12] = omega
        z[12:18] = q
        z[18:24] = qd
        z[24:30] = drive
        np.negative(tau_link, out=z[30:36])
        z[31] = nl
        if ext is not None:  # the environment's force on the tool: J^T F joins the link torques
            z[30:36] += ext
        free = pg @ z  # the step without Coulomb friction
        # Coulomb friction (Karnopp): kinetic where the motor moves and keeps its direction;
        # where it is at rest or would reverse, the friction that ends the step at rest, if it
        # is within +-tau_c (stiction), else tau_c against the would-be motion.
        tcl = self._tau_c_list if tau_c is self._tau_c else tau_c.tolist()
        if any(om):
            kin = [-tc if w > 0.0 else (tc if w < 0.0 else -0.0) for tc, w in zip(tcl, om)]  # 0 at rest
            x = free + g_m @ kin
            # moving, and still the same way with kinetic friction
            xl = x.tolist()
            for a, w in zip(xl[6:12], om):
                if not a * w > 0.0:
                    keep = [a * w > 0.0 for a, w in zip(xl[6:12], om)]
                    break
            else:
                q = x[12:18]
                self._theta, self._omega, self._q, self._qd = x[0:6], x[6:12], q, x[18:24]
                self._write_outputs(xl[0:6], xl[12:18], q)
                return
        else:  # every motor at rest: no kinetic friction, each one may stick
            kin, keep = None, (False,) * 6
        # a motor at rest or reversing (most steps: the wrist motors stand still while the main
        # axes track); per motor in plain floats -- six of them are cheaper than a dozen numpy calls.
        # (bench/bench_kernel.py's _python_core copies these lines on purpose: the bare core it times.)
        w_end = free[6:12].tolist()
        fric, rest = [0.0] * 6, []
        for j, (tc, gw) in enumerate(zip(tcl, g_wd)):
            if keep[j]:
                fric[j] = kin[j]
                continue
            stick = -w_end[j] / gw  # the friction that ends the step at rest (the 1 % coupling neglected)
            if -tc <= stick <= tc:
                fric[j] = stick
                rest.append(j)
            else:
                fric[j] = -tc if w_end[j] > 0.0 else tc
        x = free + g_m @ fric
        theta, omega = x[0:6], x[6:12]
        if rest:  # a motor held by stiction stays where it was (else it would creep by the part-step
            old = self._theta  # motion the held friction allows within the step)
            for j in rest:
                theta[j] = old[j]
                omega[j] = 0.0
        q = x[12:18]
        self._theta, self._omega, self._q, self._qd = theta, omega, q, x[18:24]
        xl = x.tolist()
        self._write_outputs(xl[0:6], xl[12:18], q)

    def _step_exact_compiled(self, dt: float, ext=None, relin: bool = False) -> None:
        """The exact branch of :meth:`_integrate` (DAC -> torque) and :meth:`_step_exact` in the
        compiled kernel (droid/_kernel.c ``exact_step``: the same operations in the same order,
        the same bits; droid.kernel).  ``relin``: the kernel's ``exact_checks`` found the
        linearisation too far (the test :meth:`_discretise` makes)."""
        got = None if relin else self._disc.get(dt)  # _discretise's own look-up, without its call
        pg, g_m, _ = got if got is not None else self._discretise(dt, self._q.tolist() if relin else None, relin)
        q, qd = self._q, self._qd
        tau_link = self.body.nle(q, qd)  # C qd + g (Pinocchio's buffer, or a new array)
        if ext is not None:
            ext = np.ascontiguousarray(ext, float)
        x = np.empty(24)
        self._enc_written = self._k.exact_step(self._view, self._consts, pg, g_m, self._theta, self._omega, q, qd,
                                               tau_link, ext, self._amps_on, self._wd_fault, self._enc_offset, x)
        self._theta, self._omega, self._q, self._qd = x[0:6], x[6:12], x[12:18], x[18:24]

    def _advance_exact_compiled(self, dt: float, disc: tuple, ext, lim) -> int | None:
        """The compiled exact branch of :meth:`_integrate` in one call (droid/_kernel.c
        ``exact_step`` with 18 arguments, its ``exact_advance``; issue 44): ``exact_checks``' guards, then, where they pass, the body's ``nle`` and
        ``exact_step`` with ``disc`` (the current linearisation's ``_disc[dt]``) -- the calls
        :meth:`_step_exact_compiled` makes, the same bits.  None when the step was made, else the
        guards' code (1: relinearise, 2: near a hard stop) with nothing called or changed."""
        if ext is not None:
            ext = np.ascontiguousarray(ext, float)
        x = np.empty(24)
        enc = self._k.exact_step(self._view, self._consts, disc[0], disc[1], self._theta, self._omega, self._q,
                                 self._qd, self.body.nle_fn, ext, self._amps_on, self._wd_fault, self._enc_offset, x,
                                 self._lin_q, self._relin_rad, self._stop_mid, lim)
        if type(enc) is int:
            return enc
        self._enc_written = enc
        self._theta, self._omega, self._q, self._qd = x[0:6], x[6:12], x[12:18], x[18:24]
        return None

    def _steps_rigid_compiled(self, n: int, h: float, ext=None) -> bool:
        """The rigid branch of :meth:`_integrate` -- the DACs -> torques, :meth:`_steps_rigid`, the
        outputs -- in one call of the compiled kernel (droid/_kernel.c ``rigid_steps``: the same
        operations in the same order, numpy's dgemv for every ``@`` and its dgesv for
        :func:`_solve`; the same bits).  False, with nothing changed, where the kernel leaves the
        advance to the Python reference: near a hard stop (:meth:`_apply_stops`), a state or
        torque not finite, a floating-point exception numpy would warn of, a singular M(q)."""
        dt = n * h
        lim = self._stop_lim_arr.get(dt)
        if lim is None:
            self._near_stop(dt, self._q.tolist())  # fills _stop_lim
            lim = self._stop_lim_arr[dt] = np.array(self._stop_lim[dt])
        if ext is not None:
            ext = np.ascontiguousarray(ext, float)
        model, mass, nle = self._rigid_body
        x = np.empty(24)
        enc = self._k_rigid.rigid_steps(self._view, self._consts, self._rigid_consts, model, mass, nle, self._qbuf,
                                        self._qdbuf, self._theta, self._omega, self._q, ext, n, h, self._amps_on,
                                        self._wd_fault, self._enc_offset, self._stop_mid, lim, x)
        if enc is None:
            return False
        self._theta, self._omega, self._q, self._qd = x[0:6], x[6:12], x[12:18], x[18:24]
        self._enc_written = enc
        self._q_list = (None, None)
        return True

    def _steps_rigid(self, n: int, h: float, drive, tau_c, ext=None) -> None:
        """Semi-implicit Euler of the rigid arm, ``(M(q) + A^-T J_m A^-1) q'' = A^-T tau_motor - C - g
        + tau_bal`` on the motor angles, at every ``h``: the reference of the compiled
        :meth:`_steps_rigid_compiled` (droid-sim's world, rigid lockstep cells)."""
        A, AinvT, Ainv = self._A, self._AinvT, self._Ainv
        theta, omega = self._theta, self._omega
        stops = self._jammed.any() or self._near_stop(n * h, self._q.tolist())
        tau_max, w0, b, bal, j_rotor = self._tau_max, self._w0, self._b, self._bal, self._J_rotor_ref
        amps, sin, mass = self._amps_on, math.sin, self.body.mass
        nle = self.body.nle
        for _ in range(n):
            q = A @ theta
            qd = A @ omega
            fade = tau_max * (omega / w0) if amps else 0.0
            tau_m = np.minimum(np.maximum(drive, -tau_max - fade), tau_max - fade)
            # C qd + g in Pinocchio's buffer, read at once by the subtraction (body.bias copies it)
            tau = AinvT @ (tau_m - b * omega) - nle(q, qd)
            tau[1] += -bal * sin(q[1])  # the balancer (_balancer)
            if ext is not None:
                tau = tau + ext
            m_tot = mass(q) + j_rotor
            # Coulomb friction with stiction, per motor: friction opposes the motion, or holds
            # the motor at rest while the net torque is below it
            qdd = _solve(m_tot, tau)
            w = omega + h * (Ainv @ qdd)
            j_eff = np.einsum("ji,jk,ki->i", A, m_tot, A)  # motor-side inertia seen by each motor
            fr = h * tau_c / j_eff  # the speed friction removes in one step [rad/s]
            omega = np.where(w > fr, w - fr, np.where(w < -fr, w + fr, 0.0))
            if stops:
                omega, _ = self._apply_stops(A @ theta, omega, A @ omega)
            theta = theta + h * omega
        self._theta, self._omega = theta, omega
        self._q = A @ theta
        self._qd = A @ omega

    def _near_stop(self, dt_s: float, ql: list) -> bool:
        """Could a hard stop engage within ``dt_s``?  (No joint outruns 360 deg/s.)  ``ql``: ``self._q``
        as floats."""
        lim = self._stop_lim.get(dt_s)
        if lim is None:
            margin = math.radians(1.0 + MAX_JOINT_SPEED_DEG_PER_S * dt_s)
            lim = self._stop_lim[dt_s] = (self._stop_half - margin).tolist()
        for qj, mid, lj in zip(ql, self._fl["stop_mid"], lim):
            if abs(qj - mid) >= lj:
                return True
        return False

    def _apply_stops(self, q, omega, qd):
        """Jammed motors stop dead; links at a hard stop moving outward stop dead."""
        omega = np.where(self._jammed, 0.0, omega)
        out = ((q >= self._stop_max) & (qd > 0.0)) | ((q <= self._stop_min) & (qd < 0.0))
        if out.any():
            qd = np.where(out, 0.0, qd)
            if not self.params.compliance:
                omega = np.where(out, 0.0, omega)
        return omega, qd

    def _read_inputs(self, dt_s: float) -> None:
        # encoder write -> counter reset to 0 (thesis §4.1.2; DROID's servo never does it)
        view = self._view
        regs = _ENCODERS.unpack_from(view, vm.ENCODER_OFFSET)
        if regs != self._enc_written:
            counts = self._floor_counts()
            for j in range(vm.N_JOINTS):
                if regs[j] != self._enc_written[j]:
                    self._enc_offset[j] = (-counts[j]) % vm.ENCODER_MODULUS
            self._enc_offset_list = self._enc_offset.tolist()
        wd, last, age = _WATCHDOGS.unpack_from(view, vm.WATCHDOG_OFFSETS[0]), self._wd_last, self._wd_age_s
        if wd[0] == last[0] and wd[1] == last[1]:  # neither register kicked (most advances: 50 Hz kicks)
            age[0] += dt_s
            age[1] += dt_s
        else:
            for i, value in enumerate(wd):
                if value != last[i]:
                    last[i] = value
                    age[i] = 0.0
                    self._wd_armed[i] = True
                else:
                    age[i] += dt_s
        if not self._wd_fault and not self._amps_on and all(self._wd_armed):
            self._amps_on = True
        timeout = self.params.watchdog_timeout_s
        if self._amps_on and (age[0] > timeout or age[1] > timeout):  # max(age) > timeout
            self._amps_on = False
            self._wd_fault = True

    def _write_outputs(self, theta_l: list | None = None, q_l: list | None = None, q=None) -> None:
        """Encoders, limit switches and AMP_STATUS into the map.  ``theta_l``/``q_l``: the state's
        motor and link angles as floats when the caller has them (``q``: the array ``q_l`` is of)."""
        if self._k is not None:  # the compiled kernel's (the same operations; droid/_kernel.c)
            q = self._q if q is None else q
            self._q_list = (q, q.tolist() if q_l is None else q_l)
            self._enc_written = self._k.write_outputs(self._view, self._consts, np.ascontiguousarray(self._theta),
                                                      np.ascontiguousarray(q), self._amps_on, self._wd_fault,
                                                      self._enc_offset)
            return
        # encoder_raw and the switch bits in plain floats (the same operations as the properties)
        if theta_l is None:
            theta_l, q_l, q = self._theta.tolist(), self._q.tolist(), self._q
        self._q_list = (q, q_l)
        floor, mod, fl = math.floor, vm.ENCODER_MODULUS, self._fl
        self._enc_written = enc = tuple([(floor(t * c) + o) % mod for t, c, o in
                                         zip(theta_l, fl["cpr"], self._enc_offset_list)])
        view = self._view
        view[vm.ENCODER_OFFSET:vm.ENCODER_OFFSET + _ENCODERS.size] = _ENCODERS.pack(*enc)
        bits = 0
        for j, (a, qj, sw) in enumerate(zip(fl["side"], q_l, fl["sw"])):
            if a * (qj - sw) > 0.0:
                bits |= 1 << j  # bit j: joint j+1's switch
        view[vm.LIMIT_SWITCH_OFFSET:vm.LIMIT_SWITCH_OFFSET + 2] = _U16.pack(bits)
        view[vm.AMP_STATUS_OFFSET:vm.AMP_STATUS_OFFSET + 2] = _AMP_STATUS[(self._amps_on, self._wd_fault)]

    def close(self) -> None:
        """Release the view on ``regs`` (needed before closing an mmap behind it)."""
        self._view.release()
