"""Dynamics and servo data of a robot file: the ``[dynamics]`` and ``[servo]`` tables.

A robot file (docs/kinematics.md) is the single source of an arm: the
kinematics and gearing the planner uses, the home switches and gains the servo
uses, and the physical data the plant twin integrates (thesis §2.3: DC servo
motors through 100:1 harmonic drives, servo amplifiers fed by +-5 V DACs, a
passive pneumatic balancer on link 2).  This module only *parses and checks*
the data; the rigid-body model is built from it in :mod:`droid.arm.rigid_body`
(Pinocchio), never here (kinematics imports no simulator).

Every value carries its provenance in the table's ``source`` sub-table: the key
maps to a string that starts with ``thesis`` (the thesis states it),
``datasheet:`` (followed by the source) or ``assumed:`` (followed by the
reasoning).  A key without provenance, an unknown key, or a non-physical value
(a mass <= 0, an inertia that is not positive definite or violates the
triangle inequality, a stiffness <= 0, ...) is a :class:`ValueError` naming
the key and the reason; :func:`droid.kinematics.robots.load_robot` prefixes
the file name.

Units are in the key names: kg, mm (centres of mass), kg m^2, N m, N m s/rad,
A, V, rad.  Per-joint lists have 6 entries, joint 1 first.  Link *i* is the
body moved by joint *i*; its centre of mass ``link_com_mm[i]`` and inertia
``link_inertia_kgm2[i]`` (about the centre of mass: Ixx Iyy Izz Ixy Ixz Iyz)
are expressed in the D-H frame *i* (the frame at the end of ``A_i``, eq. 4.1).
Motor-side quantities (rotor inertia, friction, torque constant) are per
motor; the gear ratio is the ``[gearing]`` reduction (not repeated here).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PROVENANCE = ("thesis", "datasheet:", "assumed:")

#: [dynamics] keys -> shape ("6": six numbers, "6x3", "6x6": six rows, "1": one number)
DYNAMICS_KEYS = {
    "gravity_mps2": "1",
    "link_mass_kg": "6",
    "link_com_mm": "6x3",
    "link_inertia_kgm2": "6x6",
    "rotor_inertia_kgm2": "6",
    "torque_constant_nm_per_a": "6",
    "amp_gain_a_per_v": "6",
    "amp_current_limit_a": "6",
    "motor_no_load_speed_rad_s": "6",
    "dac_full_scale_v": "1",
    "hd_stiffness_nm_per_rad": "6",
    "hd_damping_nm_s_per_rad": "6",
    "coulomb_friction_nm": "6",
    "viscous_friction_nm_s_per_rad": "6",
    "brake_torque_nm": "6",
    "balancer_moment_nm": "1",
    "hard_stop_margin_deg": "1",
}
#: keys that must be > 0 element-wise (the others must be >= 0, gravity and the balancer any sign >= 0)
POSITIVE = {"link_mass_kg", "rotor_inertia_kgm2", "torque_constant_nm_per_a", "amp_gain_a_per_v",
            "amp_current_limit_a", "dac_full_scale_v", "hd_stiffness_nm_per_rad",
            "motor_no_load_speed_rad_s"}

#: [axis_servo] keys: an arm whose own controller closes the joint loops (the Fanuc's, thesis
#: §2.4, §4.2: DROID sends it poses, never torques) -- a cascade of a position loop and a PI
#: velocity loop per joint, as industrial controllers of the time ran them.
AXIS_SERVO_KEYS = {
    "position_gain_per_s": "6",
    "velocity_bandwidth_hz": "6",
    "velocity_integral_time_s": "6",
    "velocity_feedforward": "6",
    "servo_rate_hz": "1",
}

#: [servo] keys (PID per servo tick, thesis §4.1.5.1; counts are motor encoder counts)
SERVO_KEYS = {
    "kp_dac_per_count": "6",
    "ki_dac_per_count_tick": "6",
    "kd_dac_per_count_per_tick": "6",
    "integral_limit_dac": "6",
}


@dataclass(frozen=True, eq=False)
class Dynamics:
    """The physical data of an arm (see the module docstring for units and frames)."""

    gravity_mps2: float
    link_mass_kg: np.ndarray  # (6,)
    link_com_mm: np.ndarray  # (6, 3), D-H frame i
    link_inertia_kgm2: np.ndarray  # (6, 3, 3), about the COM, D-H frame i axes
    rotor_inertia_kgm2: np.ndarray  # (6,) motor side
    torque_constant_nm_per_a: np.ndarray
    amp_gain_a_per_v: np.ndarray
    amp_current_limit_a: np.ndarray
    motor_no_load_speed_rad_s: np.ndarray  # back-EMF: the amplifier's torque fades to 0 at this speed
    dac_full_scale_v: float
    hd_stiffness_nm_per_rad: np.ndarray  # joint side
    hd_damping_nm_s_per_rad: np.ndarray  # joint side
    coulomb_friction_nm: np.ndarray  # motor side
    viscous_friction_nm_s_per_rad: np.ndarray  # motor side
    brake_torque_nm: np.ndarray  # motor side, holding brake with the amplifiers off
    balancer_moment_nm: float  # joint 2: tau = balancer_moment_nm * sin(q2) against gravity
    hard_stop_margin_deg: float  # mechanical stops this far outside the joint limits
    source: dict

    # Alike in shape only to ReisPlant's derived properties: products of the file's data.
    @property
    def motor_torque_limit_nm(self) -> np.ndarray:
        """Largest motor torque [N m] the amplifier delivers (current limit x k_t)."""
        return self.torque_constant_nm_per_a * self.amp_current_limit_a

    @property
    def torque_per_volt_nm_per_v(self) -> np.ndarray:
        return self.torque_constant_nm_per_a * self.amp_gain_a_per_v


@dataclass(frozen=True)
class ServoGains:
    """The PID gains of the servo (thesis §4.1.5.1), per servo tick."""

    kp_dac_per_count: tuple
    ki_dac_per_count_tick: tuple
    kd_dac_per_count_per_tick: tuple
    integral_limit_dac: tuple
    source: dict


@dataclass(frozen=True)
class AxisServo:
    """The joint loops of an arm's own controller (``[axis_servo]``): per joint a position loop
    ``w_cmd = ff * w_ref + kp (q_ref - q)`` [rad/s] and a PI velocity loop of bandwidth
    ``velocity_bandwidth_hz`` (the torque ``J w_v (e + integral(e) / Ti)``), run at
    ``servo_rate_hz``."""

    position_gain_per_s: np.ndarray
    velocity_bandwidth_hz: np.ndarray
    velocity_integral_time_s: np.ndarray
    velocity_feedforward: np.ndarray
    servo_rate_hz: float
    source: dict


def _shape(table: str, key: str, value, shape: str) -> np.ndarray:
    def num(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"[{table}] {key}: expected finite numbers")
        return float(v)

    if shape == "1":
        return np.array(num(value))
    if not isinstance(value, list) or len(value) != 6:
        raise ValueError(f"[{table}] {key}: expected a list of 6 " + ("numbers" if shape == "6" else "rows"))
    if shape == "6":
        return np.array([num(v) for v in value])
    width = int(shape.split("x")[1])
    rows = []
    for row in value:
        if not isinstance(row, list) or len(row) != width:
            raise ValueError(f"[{table}] {key}: expected 6 rows of {width} numbers")
        rows.append([num(v) for v in row])
    return np.array(rows)


def _provenance(table: str, data: dict, keys: dict) -> dict:
    src = data.get("source")
    if not isinstance(src, dict):
        raise ValueError(f"[{table}.source]: missing (every value needs 'thesis', 'datasheet: ...' or 'assumed: ...')")
    unknown = set(src) - set(keys)
    if unknown:
        raise ValueError(f"[{table}.source]: unknown key(s) {', '.join(sorted(unknown))}")
    for key in keys:
        text = src.get(key)
        if not isinstance(text, str) or not text.startswith(PROVENANCE):
            raise ValueError(f"[{table}.source] {key}: missing provenance (start with 'thesis', "
                             f"'datasheet: <source>' or 'assumed: <reasoning>')")
        if text.startswith(("datasheet:", "assumed:")) and len(text.split(":", 1)[1].strip()) < 3:
            raise ValueError(f"[{table}.source] {key}: say which datasheet / why it is assumed")
    return dict(src)


def _parse(table: str, data, keys: dict) -> tuple[dict, dict]:
    if not isinstance(data, dict):
        raise ValueError(f"[{table}] must be a table")
    unknown = set(data) - set(keys) - {"source"}
    if unknown:
        raise ValueError(f"[{table}]: unknown key(s) {', '.join(sorted(unknown))}")
    missing = set(keys) - set(data)
    if missing:
        raise ValueError(f"[{table}]: missing key(s) {', '.join(sorted(missing))}")
    values = {k: _shape(table, k, data[k], shape) for k, shape in keys.items()}
    return values, _provenance(table, data, keys)


def _as_fields(values: dict, keys: dict) -> dict:
    """A parsed table's ``values`` as its dataclass's fields: a one-number key (shape "1") as a
    float, the others as parsed (arrays)."""
    return {k: float(a) if keys[k] == "1" else a for k, a in values.items()}


def inertia_matrix(six) -> np.ndarray:
    """3x3 inertia [kg m^2] from (Ixx, Iyy, Izz, Ixy, Ixz, Iyz)."""
    xx, yy, zz, xy, xz, yz = (float(v) for v in six)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def check_inertia(i: int, inertia: np.ndarray) -> None:
    """Raise ValueError unless the inertia of link i+1 is positive definite and physical."""
    w = np.linalg.eigvalsh(inertia)
    if np.min(w) <= 0.0:
        raise ValueError(f"[dynamics] link_inertia_kgm2: link {i + 1}: inertia is not positive definite "
                         f"(principal moments {', '.join(f'{x:.4g}' for x in w)})")
    a, b, c = sorted(w)
    if c > a + b + 1e-9 * c:
        raise ValueError(f"[dynamics] link_inertia_kgm2: link {i + 1}: principal moments violate the triangle "
                         f"inequality ({a:.4g} + {b:.4g} < {c:.4g}): no rigid body has them")


def dynamics_from_table(data) -> Dynamics:
    """Parse and check a ``[dynamics]`` table."""
    v, src = _parse("dynamics", data, DYNAMICS_KEYS)
    for key, arr in v.items():
        if key in POSITIVE and np.any(arr <= 0):
            raise ValueError(f"[dynamics] {key}: must be > 0 (non-physical)")
        if key not in POSITIVE and np.any(arr < 0) and key != "link_com_mm" and key != "link_inertia_kgm2":
            raise ValueError(f"[dynamics] {key}: must be >= 0 (non-physical)")
    inertias = np.array([inertia_matrix(row) for row in v["link_inertia_kgm2"]])
    for i, inertia in enumerate(inertias):
        check_inertia(i, inertia)
    return Dynamics(**{**_as_fields(v, DYNAMICS_KEYS), "link_inertia_kgm2": inertias}, source=src)


def axis_servo_from_table(data) -> AxisServo:
    """Parse and check an ``[axis_servo]`` table (gains, bandwidths, times, rate > 0; feed-forward 0..1)."""
    v, src = _parse("axis_servo", data, AXIS_SERVO_KEYS)
    for key in ("position_gain_per_s", "velocity_bandwidth_hz", "velocity_integral_time_s", "servo_rate_hz"):
        if np.any(v[key] <= 0):
            raise ValueError(f"[axis_servo] {key}: must be > 0 (non-physical)")
    if np.any(v["velocity_feedforward"] < 0) or np.any(v["velocity_feedforward"] > 1):
        raise ValueError("[axis_servo] velocity_feedforward: must lie within [0, 1]")
    # the twin integrates the velocity loop explicitly at the servo rate: it must be well inside it
    if np.any(2 * math.pi * v["velocity_bandwidth_hz"] / v["servo_rate_hz"] > 0.5):
        raise ValueError("[axis_servo] velocity_bandwidth_hz: must be below servo_rate_hz / (4 pi) "
                         "(a loop that fast cannot be run at that rate)")
    return AxisServo(**_as_fields(v, AXIS_SERVO_KEYS), source=src)


def servo_from_table(data) -> ServoGains:
    """Parse and check a ``[servo]`` table (gains >= 0, integral limits > 0)."""
    v, src = _parse("servo", data, SERVO_KEYS)
    for key, arr in v.items():
        if np.any(arr < 0):
            raise ValueError(f"[servo] {key}: gains must be >= 0")
    if np.any(v["integral_limit_dac"] <= 0):
        raise ValueError("[servo] integral_limit_dac: must be > 0")
    return ServoGains(**{k: tuple(float(x) for x in arr) for k, arr in v.items()}, source=src)
