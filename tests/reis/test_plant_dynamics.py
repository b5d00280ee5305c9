"""The arm twin's physics from its robot file (issue 13): Pinocchio model, compliance, bad files."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.robot_files import assert_refused, spoiled

from droid.kinematics import load_robot
from droid.arm.rigid_body import DhError, RigidBody
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.vme import VmeBus

V15 = Path(load_robot("reis_v15").source)


@pytest.mark.parametrize("robot", ["reis_v15", "reis_class_b"])
def test_pinocchio_model_has_the_robot_files_kinematics(robot):
    m = load_robot(robot)
    rb = RigidBody(m.dh, m.dynamics)
    rng = np.random.default_rng(1)
    for q in rng.uniform(-120, 120, (20, 6)):
        assert np.allclose(rb.wcp_mm(q), m.fk(q), atol=1e-9)


def test_mass_matrix_depends_on_the_configuration_and_couples_joints():
    m = load_robot("reis_v15")
    rb = RigidBody(m.dh, m.dynamics)
    out = rb.mass(np.radians([0, 0, 0, 0, 0, 0]))
    folded = rb.mass(np.radians([0, 0, 90, 0, 0, 0]))  # forearm up: nearer joint 1's axis
    assert out[0, 0] > 1.5 * folded[0, 0]
    assert abs(out[1, 2]) > 0.1  # joints 2 and 3 are inertially coupled
    assert np.all(np.linalg.eigvalsh(out) > 0)


def test_servo_and_plant_read_the_same_home_switches():
    for robot in ("reis_v15", "reis_class_b"):
        m = load_robot(robot)
        sp = ServoParams.from_robot(robot)
        pp = ReisPlantParams(robot=robot)
        assert np.allclose(sp.home_switch_deg, m.home_switch_deg)
        assert np.allclose(pp.switch_joint_deg, m.home_switch_deg)
        # the servo searches in count space: the joint direction times the gearing's sign
        signs = np.sign(np.diag(m.gearing.joint_to_counts_matrix))
        assert tuple(sp.home_search_dir) == tuple(int(s) for s in signs * m.home_search_dir)
    assert ServoParams().home_switch_deg == ServoParams.from_robot("reis_v15").home_switch_deg
    assert ServoParams.from_robot("reis_class_b").home_switch_deg != ServoParams().home_switch_deg


def test_home_error_moves_the_true_switch_only():
    err = (0.0, 0.3, -0.2, 0.1, 0.4, 0.0)
    pp = ReisPlantParams(home_error_deg=err)
    assert np.allclose(np.asarray(pp.switch_joint_deg) - load_robot("reis_v15").home_switch_deg, err)


def test_drives_deflect_under_gravity_and_the_encoders_see_the_motors():
    """At rest under gravity the link sits K^-1 tau from the motor (harmonic-drive stiffness)."""
    plant = ReisPlant(seed=1, initial_joint_deg=np.zeros(6))
    defl = plant.joint_deg - plant.motor_joint_deg
    tau = plant.gravity_joint_torque_nm(np.zeros(6))
    expect = np.degrees(tau / load_robot("reis_v15").dynamics.hd_stiffness_nm_per_rad)
    assert np.allclose(defl, expect, atol=1e-4)
    assert abs(defl[2]) > 0.05  # the forearm's weight twists drive 3 measurably
    rigid = ReisPlant(ReisPlantParams(compliance=False), seed=1, initial_joint_deg=np.zeros(6))
    assert np.allclose(rigid.joint_deg, rigid.motor_joint_deg, atol=1e-12)


def test_amplifier_saturates_and_back_emf_caps_the_speed():
    plant = ReisPlant(seed=2, initial_joint_deg=np.zeros(6))
    bus = VmeBus.from_buffer(plant.regs)
    for _ in range(300):  # 0.6 s of full positive command on joint 1 (vertical axis: no gravity)
        bus.write_dacs([2047, 0, 0, 0, 0, 0])
        bus.kick_watchdog()
        plant.advance(0.002)
    w = plant.motor_speed_counts_per_s[0] / (4000 / (2 * np.pi))
    w0 = load_robot("reis_v15").dynamics.motor_no_load_speed_rad_s[0]
    assert 0.5 * w0 < abs(w) < w0  # limited by the back-EMF, not by the integration
    for _ in range(500):  # 1 s more: the link reaches its mechanical stop
        bus.write_dacs([2047, 0, 0, 0, 0, 0])
        bus.kick_watchdog()
        plant.advance(0.002)
    stop = load_robot("reis_v15").joint_max_deg[0] + load_robot("reis_v15").dynamics.hard_stop_margin_deg
    assert abs(abs(plant.joint_deg[0]) - stop) < 0.5
    bus.close()


def test_dh_errors_change_the_true_arm_not_the_model():
    err = DhError(a_mm=(0, 0.5, 0, 0, 0, 0), alpha_deg=(0.02, 0, 0, 0, 0, 0))
    plant = ReisPlant(ReisPlantParams(dh_error=err), seed=1, initial_joint_deg=np.zeros(6))
    model = load_robot("reis_v15")
    d = plant.wcp_true()[:3, 3] - model.fk(plant.joint_deg)[:3, 3]
    assert 0.3 < np.linalg.norm(d) < 2.0


def _bad_file(tmp_path, old, new):
    return spoiled(V15, tmp_path, old, new)


# Rows alike in shape only to test_gmf1_dynamics': the V15's file, its own keys.
@pytest.mark.parametrize("old, new, words", [
    ("link_mass_kg = [60.0,", "link_mass_kg = [-60.0,", ["link_mass_kg", "outside [0,"]),  # droid.numbers' range
    ("link_mass_kg = [60.0,", "link_mass_kg = [0.0,", ["link_mass_kg", "> 0"]),  # the loader's own rule
    ("  [2.4,    1.2,    2.4,    0.0, 0.0, 0.0],", "  [2.4,    1.2,    -2.4,    0.0, 0.0, 0.0],",
     ["link_inertia_kgm2", "positive definite"]),
    ("  [2.4,    1.2,    2.4,    0.0, 0.0, 0.0],", "  [0.1,    0.1,    2.4,    0.0, 0.0, 0.0],",
     ["link_inertia_kgm2", "triangle"]),
    ("hd_stiffness_nm_per_rad = [5.4e4,", "hd_stiffness_nm_per_rad = [0.0,", ["hd_stiffness_nm_per_rad", "> 0"]),
    ("balancer_moment_nm = 250.0", "balancer_moment_nm = 250.0\nspring_rate = 3", ["unknown", "spring_rate"]),
    ("rotor_inertia_kgm2 = [", "#rotor_inertia_kgm2 = [", ["missing", "rotor_inertia_kgm2"]),
    ('rotor_inertia_kgm2 = "assumed:', 'rotor_inertia_kgm2 = "guess:', ["provenance", "rotor_inertia_kgm2"]),
])
def test_non_physical_dynamics_are_refused_naming_file_key_and_reason(tmp_path, old, new, words):
    p = _bad_file(tmp_path, old, new)
    assert_refused(p, words)
    # and a program that loads it exits 2 with one line, no traceback
    r = subprocess.run([sys.executable, "-m", "droid.kinematics.cli", "fk", "--robot", str(p), "0", "0", "0", "0",
                        "0", "0"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert str(p) in r.stderr and words[0] in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def _servo_move_trace(integrator: str, plant_hz: int):
    """Home next to the switches, then a 1 s minimum-jerk servo move of all six joints; link angles [deg]."""
    from droid.sim.reis.lockstep import (LockstepRates, ReisLockstep, min_jerk_waypoints, run_homing,
                                         waypoint_commander)
    from droid.subunits.reis.servo import ServoCore
    from droid.subunits.reis.servo_params import Mode

    pp = ReisPlantParams(integrator=integrator, substep_s=1.0 / plant_hz)
    plant = ReisPlant(pp, seed=2, initial_joint_deg=np.asarray(pp.switch_joint_deg) + 0.3)
    # homing without the at-rest bracketing (step 5): a probe that lands within a count of an edge
    # can read differently on the two integrators and add a probe, shifting the move in time
    servo = ServoCore(ServoParams(home_probe_resolution_counts=0))
    ls = ReisLockstep(plant, servo, rates=LockstepRates(plant_hz=plant_hz, command_hz=60))
    ls.run(0.05)
    run_homing(ls)
    assert ls.servo.homed
    M = np.asarray(ls.servo.params.joint_to_counts)
    goal = np.rint(M @ np.array([40.0, -25.0, 30.0, -60.0, 45.0, 90.0])).astype(int)
    wp = min_jerk_waypoints(ls.servo.encoder_cmd, goal, 1.0)
    tr = ls.run(1.5, waypoint_commander(wp, Mode.NORMAL, first_index=ls.command_index))
    assert np.abs(tr.encoder_pos[-1] - goal).max() <= 10  # arrived
    return tr.joint_deg


def test_the_exact_integrator_agrees_with_the_converged_reference_on_a_servo_move():
    """The default 2 ms zero-order-hold step against semi-implicit Euler at 10 kHz (converged to
    ~0.002 deg): within EXACT_BOUND_DEG on every joint, all along the move."""
    from droid.sim.reis.plant import EXACT_BOUND_DEG

    ref = _servo_move_trace("substep", 10000)
    fast = _servo_move_trace("exact", 2000)
    assert np.abs(ref - fast).max() < EXACT_BOUND_DEG


def test_unknown_integrator_is_refused():
    with pytest.raises(ValueError, match="unknown integrator"):
        ReisPlantParams(integrator="rk4")
