"""The simulated Reis Robotstar V15: VME register map + joint dynamics.

Thesis §2.3 and §4.1.2 describe the hardware this twin reproduces: six DC
servo motors through 100:1 harmonic drives, each behind a servo amplifier fed
by a signed 12-bit DAC (+-5 V), a 16-bit quadrature encoder counter per motor
(4000 counts per motor revolution, arbitrary value at power-up), a limit
switch per joint at a known position, two watchdog timers that disable the
amplifiers when they are not rewritten in time (a latched fault, cleared only
by a power cycle), and a passive pneumatic balancer on link 2.

Model (per motor, motor side, semi-implicit Euler at ``substep_s``)::

    J_eff * dw/dt = tau_amp + A^T tau_gravity(q) - b*w - tau_c*sign(w)
    tau_amp = clip(dac/2048 * 5 V * k_tau, +-tau_max)        (0 when amps are off)
    m = theta * 4000/(2 pi)   [counts]       q_deg = M^-1 m   (droid.kinematics.gearing)

with ``q_rad = A theta`` (A = pi/180 * 4000/(2 pi) * M^-1, so generalized
torques map as tau_motor = A^T tau_joint), J_eff = J_motor + diag(A^T J_link A)
(constant link inertia, cross terms of the 1 % coupling neglected), viscous
friction implicit, Coulomb friction with stiction (a motor at rest stays at rest
while the net torque is below tau_c).  When the amplifiers are off a holding
brake adds ``brake_torque_nm`` of friction.  Gravity acts on joints 2 and 3
(upper arm from vertical, forearm horizontal at home); the balancer cancels
``balancer_fraction`` of the joint-2 load at the current q2 with q3 = 0.

Register traffic per :meth:`ReisPlant.advance`: DACs and watchdog registers are
read at the start, encoders, limit switches and AMP_STATUS written at the end
(layout: :mod:`droid.subunits.reis.vme_map`).  Everything is seeded and
deterministic.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import numpy as np

from droid.subunits.reis import vme_map as vm
from droid.subunits.reis.robot_file import joint_to_counts_tuple, load_gearing

Six = tuple[float, float, float, float, float, float]
MAX_JOINT_SPEED_DEG_PER_S = 360.0  # bound used to skip hard-stop checks far from the stops


def _reis_joint_to_counts() -> tuple[tuple[float, ...], ...]:
    return joint_to_counts_tuple(load_gearing())


@dataclass(frozen=True)
class ReisPlantParams:
    """Physical parameters of the simulated arm (DROID's estimates; thesis gives none)."""

    joint_to_counts: tuple[tuple[float, ...], ...] = field(default_factory=_reis_joint_to_counts)
    """M [motor counts per joint degree], counts = M @ q_deg (gearing + coupling)."""
    substep_s: float = 0.0005  # integration step (2 kHz)
    encoder_counts_per_rev: float = 4000.0  # motor-side quadrature counts per motor revolution
    motor_inertia_kgm2: Six = (3.0e-4, 3.0e-4, 2.0e-4, 5.0e-5, 5.0e-5, 3.0e-5)
    link_inertia_kgm2: Six = (12.0, 10.0, 3.0, 0.15, 0.12, 0.03)  # about each joint axis
    viscous_friction_nm_s_per_rad: Six = (1.0e-3, 1.0e-3, 8.0e-4, 2.0e-4, 2.0e-4, 1.0e-4)  # motor side
    coulomb_friction_nm: Six = (0.06, 0.06, 0.05, 0.02, 0.02, 0.015)  # motor side
    torque_per_volt_nm_per_v: Six = (0.6, 0.6, 0.6, 0.2, 0.2, 0.2)  # amplifier + motor
    amp_torque_limit_nm: Six = (2.5, 2.5, 2.5, 0.8, 0.8, 0.8)  # amplifier current limit
    brake_torque_nm: Six = (3.0, 3.0, 3.0, 1.0, 1.0, 1.0)  # holding brake when amps are off
    gravity_mps2: float = 9.81
    upper_arm_length_m: float = 0.600  # link 2 (Table 4.1)
    upper_arm_mass_kg: float = 25.0
    upper_arm_com_m: float = 0.30  # from joint 2
    forearm_mass_kg: float = 20.0  # forearm + wrist + payload
    forearm_com_m: float = 0.30  # from joint 3
    balancer_fraction: float = 0.7  # share of the joint-2 load the pneumatic balancer carries
    switch_joint_deg: Six = (2.0, -3.0, 4.0, -2.5, 3.5, -5.0)  # home limit switch positions
    switch_active_side: tuple[int, ...] = (1, 1, 1, 1, 1, 1)  # +1: active for q > switch
    hard_stop_min_deg: Six = (-170.0, -110.0, -130.0, -270.0, -130.0, -350.0)
    hard_stop_max_deg: Six = (170.0, 110.0, 130.0, 270.0, 130.0, 350.0)
    watchdog_timeout_s: float = 0.100  # a watchdog register unchanged this long latches amps off
    initial_joint_deg: Six = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # pose at power-up (centre)
    initial_spread_deg: float = 15.0  # power-up pose = centre + seeded uniform +-spread


class ReisPlant:
    """The robot behind the VME register map.  ``regs`` is the map's bytes.

    ``regs`` may be supplied (e.g. an mmap of a POSIX shared-memory object,
    :mod:`droid.sim.vme_shm`); by default it is a private bytearray.
    ``encoder_power_up_counts`` and ``initial_joint_deg`` override the seeded
    power-up values (tests).
    """

    def __init__(
        self,
        params: ReisPlantParams | None = None,
        seed: int = 0,
        *,
        regs=None,
        encoder_power_up_counts=None,
        initial_joint_deg=None,
    ):
        p = self.params = params if params is not None else ReisPlantParams()
        self._rng = np.random.default_rng(seed)
        self.regs = regs if regs is not None else bytearray(vm.MAP_SIZE)
        self._view = memoryview(self.regs).cast("B")
        if self._view.nbytes < vm.MAP_SIZE:
            raise ValueError(f"register buffer has {self._view.nbytes} bytes, need {vm.MAP_SIZE}")
        self._view[: vm.MAP_SIZE] = bytes(vm.MAP_SIZE)

        m = np.asarray(p.joint_to_counts, float)
        self._m = m  # counts per deg
        self._minv = np.linalg.inv(m)  # deg per count
        self._counts_per_rad = p.encoder_counts_per_rev / (2.0 * math.pi)
        a = math.radians(1.0) * self._counts_per_rad * self._minv  # q_rad = A @ theta_rad
        j_link = np.asarray(p.link_inertia_kgm2, float)
        j_eff = np.asarray(p.motor_inertia_kgm2, float) + (a * a * j_link[:, None]).sum(axis=0)
        # the integrator works on plain Python floats (6 joints: faster than numpy)
        self._j_eff = [float(x) for x in j_eff]
        self._minv_rows = [tuple(float(c) for c in row) for row in self._minv * self._counts_per_rad]  # deg/rad
        self._a_grav2 = [float(x) for x in a[1]]  # tau_motor += A[1, i] * tau_joint2
        self._a_grav3 = [float(x) for x in a[2]]
        self._a_diag = [float(x) for x in np.diag(a)]
        self._b = [float(x) for x in p.viscous_friction_nm_s_per_rad]
        self._tau_c = [float(x) for x in p.coulomb_friction_nm]
        self._tau_brake = [float(x) for x in p.brake_torque_nm]
        scale = vm.DAC_FULL_SCALE_V / (vm.DAC_MAX + 1)
        self._tau_per_dac = [float(x) * scale for x in p.torque_per_volt_nm_per_v]
        self._tau_max = [float(x) for x in p.amp_torque_limit_nm]
        self._sw = [float(x) for x in p.switch_joint_deg]
        self._side = [float(x) for x in p.switch_active_side]
        self._stop_min = [float(x) for x in p.hard_stop_min_deg]
        self._stop_max = [float(x) for x in p.hard_stop_max_deg]
        g = p.gravity_mps2
        self._g_sin2 = g * (p.upper_arm_mass_kg * p.upper_arm_com_m + p.forearm_mass_kg * p.upper_arm_length_m)
        self._g_cos23 = g * p.forearm_mass_kg * p.forearm_com_m

        if initial_joint_deg is None:
            spread = self._rng.uniform(-p.initial_spread_deg, p.initial_spread_deg, vm.N_JOINTS)
            initial_joint_deg = np.asarray(p.initial_joint_deg, float) + spread
        q0 = np.asarray(initial_joint_deg, float)
        self._theta = [float(x) for x in (m @ q0) / self._counts_per_rad]  # motor angles [rad], 0 at home
        self._omega = [0.0] * vm.N_JOINTS  # motor speeds [rad/s]
        self._jammed = [False] * vm.N_JOINTS
        self.time_s = 0.0
        self._power_up(encoder_power_up_counts)

    # -- power ---------------------------------------------------------------
    def _power_up(self, encoder_counts=None) -> None:
        if encoder_counts is None:
            encoder_counts = self._rng.integers(0, vm.ENCODER_MODULUS, vm.N_JOINTS)
        counts = self._floor_counts()
        self._enc_offset = [(int(e) - c) % vm.ENCODER_MODULUS for e, c in zip(encoder_counts, counts)]
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
        self._omega = [0.0] * vm.N_JOINTS
        self._power_up()

    @property
    def amps_on(self) -> bool:
        """True while the servo amplifiers are powered (no watchdog latch)."""
        return self._amps_on

    # -- state -------------------------------------------------------------------
    def _floor_counts(self) -> list[int]:
        cpr = self._counts_per_rad
        return [math.floor(th * cpr) for th in self._theta]

    @property
    def motor_counts(self) -> np.ndarray:
        """True motor positions [counts, float], 0 at the home pose (q = 0)."""
        return np.array(self._theta) * self._counts_per_rad

    @property
    def motor_speed_counts_per_s(self) -> np.ndarray:
        """Motor speeds [counts/s]."""
        return np.array(self._omega) * self._counts_per_rad

    @property
    def joint_deg(self) -> np.ndarray:
        """Joint angles [deg] (q = M^-1 m)."""
        return self._minv @ self.motor_counts

    @property
    def limit_switches(self) -> tuple[bool, ...]:
        """Limit switch states, joint 1 first (cam: active on the ``switch_active_side``)."""
        t0, t1, t2, t3, t4, t5 = self._theta
        q = [r0 * t0 + r1 * t1 + r2 * t2 + r3 * t3 + r4 * t4 + r5 * t5 for r0, r1, r2, r3, r4, r5 in self._minv_rows]
        return tuple(side * (qi - sw) > 0.0 for side, qi, sw in zip(self._side, q, self._sw))

    @property
    def encoder_raw(self) -> tuple[int, ...]:
        """The six 16-bit counter values as the hardware shows them [counts]."""
        return tuple((c + o) % vm.ENCODER_MODULUS for c, o in zip(self._floor_counts(), self._enc_offset))

    def jam(self, joint: int, jammed: bool = True) -> None:
        """Fault injection: block motor ``joint`` (0-based) mechanically, or release it."""
        self._jammed[joint] = bool(jammed)
        if jammed:
            self._omega[joint] = 0.0

    # -- simulation -------------------------------------------------------------
    def gravity_joint_torque_nm(self, q_deg) -> tuple[float, float]:
        """Net gravity torques on joints 2 and 3 [N m] after the balancer."""
        q2 = math.radians(q_deg[1])
        cos23 = self._g_cos23 * math.cos(q2 + math.radians(q_deg[2]))
        sin2 = self._g_sin2 * math.sin(q2)
        tau2 = sin2 + cos23 - self.params.balancer_fraction * (sin2 + self._g_cos23 * math.cos(q2))
        return tau2, cos23

    def advance(self, dt_s: float) -> None:
        """Read DACs/watchdogs from ``regs``, integrate ``dt_s`` (a whole number of
        substeps), write encoders, limit switches and AMP_STATUS."""
        p = self.params
        n = int(round(dt_s / p.substep_s))
        if n < 1 or abs(n * p.substep_s - dt_s) > 1e-9:
            raise ValueError(f"advance({dt_s}) is not a whole number of {p.substep_s} s substeps")
        self._read_inputs(dt_s)
        dacs = struct.unpack_from(vm.DACS_FORMAT, self._view, vm.DAC_OFFSET)
        joints = range(vm.N_JOINTS)
        if self._amps_on:
            drive = []
            for i in joints:
                tau = min(vm.DAC_MAX, max(vm.DAC_MIN, dacs[i])) * self._tau_per_dac[i]
                drive.append(min(self._tau_max[i], max(-self._tau_max[i], tau)))
            tau_c = self._tau_c
        else:
            drive = [0.0] * vm.N_JOINTS
            tau_c = [c + b for c, b in zip(self._tau_c, self._tau_brake)]
        h = p.substep_s
        h_over_j = [h / j for j in self._j_eff]
        damp = [1.0 / (1.0 + b * hj) for b, hj in zip(self._b, h_over_j)]
        dw_c = [c * hj for c, hj in zip(tau_c, h_over_j)]
        theta, omega = self._theta, self._omega
        rows = self._minv_rows
        stops_active = any(self._jammed) or self._near_stop(theta, n * h)
        g_sin2, g_cos23, bal = self._g_sin2, self._g_cos23, self.params.balancer_fraction
        deg = math.pi / 180.0
        per_joint = list(zip(range(vm.N_JOINTS), drive, h_over_j, damp, dw_c, self._a_grav2, self._a_grav3))
        for _ in range(n):
            t0, t1, t2, t3, t4, t5 = theta
            r1, r2 = rows[1], rows[2]
            q2 = deg * (r1[0] * t0 + r1[1] * t1 + r1[2] * t2 + r1[3] * t3 + r1[4] * t4 + r1[5] * t5)
            q3 = deg * (r2[0] * t0 + r2[1] * t1 + r2[2] * t2 + r2[3] * t3 + r2[4] * t4 + r2[5] * t5)
            cos23 = g_cos23 * math.cos(q2 + q3)  # gravity (see gravity_joint_torque_nm)
            sin2 = g_sin2 * math.sin(q2)
            tau2 = sin2 + cos23 - bal * (sin2 + g_cos23 * math.cos(q2))
            for i, drv, hj, dmp, dwc, a2, a3 in per_joint:
                w = (omega[i] + hj * (drv + a2 * tau2 + a3 * cos23)) * dmp
                w = w - dwc if w > dwc else (w + dwc if w < -dwc else 0.0)  # Coulomb + stiction
                omega[i] = w
            if stops_active:
                self._apply_stops(theta, omega)
            for i in range(vm.N_JOINTS):
                theta[i] += h * omega[i]
        self.time_s += n * h
        self._write_outputs()

    def _near_stop(self, theta, dt_s: float) -> bool:
        """Could a hard stop engage within ``dt_s``?  (No joint outruns 360 deg/s.)"""
        margin = 1.0 + MAX_JOINT_SPEED_DEG_PER_S * dt_s
        t0, t1, t2, t3, t4, t5 = theta
        for r, lo, hi in zip(self._minv_rows, self._stop_min, self._stop_max):
            q = r[0] * t0 + r[1] * t1 + r[2] * t2 + r[3] * t3 + r[4] * t4 + r[5] * t5
            if q <= lo + margin or q >= hi - margin:
                return True
        return False

    def _apply_stops(self, theta, omega) -> None:
        """Jammed motors and joints at a hard stop moving outward stop dead."""
        t0, t1, t2, t3, t4, t5 = theta
        for i, (r, lo, hi) in enumerate(zip(self._minv_rows, self._stop_min, self._stop_max)):
            q = r[0] * t0 + r[1] * t1 + r[2] * t2 + r[3] * t3 + r[4] * t4 + r[5] * t5
            dq = self._a_diag[i] * omega[i]
            if self._jammed[i] or (q >= hi and dq > 0.0) or (q <= lo and dq < 0.0):
                omega[i] = 0.0

    def _read_inputs(self, dt_s: float) -> None:
        # encoder write -> counter reset to 0 (thesis §4.1.2; DROID's servo never does it)
        regs = struct.unpack_from(vm.ENCODERS_FORMAT, self._view, vm.ENCODER_OFFSET)
        if regs != self._enc_written:
            counts = self._floor_counts()
            for j in range(vm.N_JOINTS):
                if regs[j] != self._enc_written[j]:
                    self._enc_offset[j] = (-counts[j]) % vm.ENCODER_MODULUS
        for i, off in enumerate(vm.WATCHDOG_OFFSETS):
            value = struct.unpack_from(vm.U16_FORMAT, self._view, off)[0]
            if value != self._wd_last[i]:
                self._wd_last[i] = value
                self._wd_age_s[i] = 0.0
                self._wd_armed[i] = True
            else:
                self._wd_age_s[i] += dt_s
        if not self._wd_fault and not self._amps_on and all(self._wd_armed):
            self._amps_on = True
        if self._amps_on and max(self._wd_age_s) > self.params.watchdog_timeout_s:
            self._amps_on = False
            self._wd_fault = True

    def _write_outputs(self) -> None:
        self._enc_written = self.encoder_raw
        vm.store(self._view, vm.ENCODER_OFFSET, vm.ENCODERS_FORMAT, *self._enc_written)
        bits = 0
        for j, active in enumerate(self.limit_switches):
            bits |= int(active) << j
        vm.store(self._view, vm.LIMIT_SWITCH_OFFSET, vm.U16_FORMAT, bits)
        status = (vm.AMP_STATUS_POWERED if self._amps_on else 0) | (
            vm.AMP_STATUS_WATCHDOG_FAULT if self._wd_fault else 0
        )
        vm.store(self._view, vm.AMP_STATUS_OFFSET, vm.U16_FORMAT, status)

    def close(self) -> None:
        """Release the view on ``regs`` (needed before closing an mmap behind it)."""
        self._view.release()
