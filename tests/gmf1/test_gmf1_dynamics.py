"""The Fanuc twin's arm from its own robot file (issue 13 items 1-2): [dynamics] + [axis_servo]
behind KAREL's trajectory; DONE after the in-position check; bad files refused.  Lockstep only."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from droid.kinematics.transforms import pose_to_T
import pytest

from tests.robot_files import assert_refused, spoiled

from droid.kinematics import RobotFileError, load_robot
from droid.sim.gmf1.controller import KarelParams, Motion
from droid.arm.arm_dynamics import ArmDynamics
from droid.sim.gmf1.lockstep import Gmf1Lockstep
from droid.arm.rigid_body import RigidBody

S400 = Path(load_robot("fanuc_s400").source)
TARGET = [1060.51, -165.66, 2295.23, -170.0, 30.0, -160.0]  # global frame, reachable (test_gmf1_lockstep)


def test_the_fanuc_file_carries_its_own_sourced_dynamics():
    m = load_robot("fanuc_s400")
    assert m.dynamics is not None and m.axis_servo is not None
    for table in (m.dynamics.source, m.axis_servo.source):
        assert all(v.startswith(("thesis", "datasheet:", "assumed:")) for v in table.values())
    rb = RigidBody(m.dh, m.dynamics)
    g = rb.gravity(np.radians([0, 60, 0, 0, 0, 0]))
    assert abs(g[0]) < 1e-6 and abs(g[1]) > 500.0  # joint 1 vertical; joint 2 carries the arm
    # its own data, not the Reis's
    assert not np.allclose(m.dynamics.link_mass_kg, load_robot("reis_v15").dynamics.link_mass_kg)


def test_the_arm_lags_the_path_by_v_over_kp_and_settles_on_it_under_gravity():
    m = load_robot("fanuc_s400")
    q0 = np.array([10.0, 15.0, 5.0, 0.0, 30.0, 0.0])
    q1 = np.array([30.0, 40.0, 20.0, 20.0, 60.0, 30.0])
    arm = ArmDynamics(m, q0)
    mo = Motion(q0, q1, 0.0, 2.0, 0.3, 1)
    lag = []
    for k in range(1, 3001):
        t = k / 1000.0
        arm.advance(t, mo.q_at(t))
        if abs(t - 1.0) < 1e-9:  # cruising: the position loop lags by v / kp
            lag = mo.q_at(t) - arm.q_motor_deg
    v = (q1 - q0) / (2.0 - 0.3)  # cruise speed [deg/s]
    np.testing.assert_allclose(lag, v / m.axis_servo.position_gain_per_s, rtol=0.1)
    np.testing.assert_allclose(arm.q_motor_deg, q1, atol=1e-6)  # the integral removes the droop
    sag = arm.q_deg - arm.q_motor_deg  # the reducers twist under the gravity load
    assert 1e-4 < abs(sag[1]) < 0.05 and abs(sag[0]) < 1e-6


def test_a_dynamic_gmf1_homes_moves_and_reports_done_only_in_position():
    g = Gmf1Lockstep(params=KarelParams(dynamics=True))
    g.run_ticks(2)
    assert g.home()
    s = g.status()
    assert int(s["homed"]) == 1 and np.all(np.abs(s["encoder_pos"]) <= 1)
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(2.0))
    lag = []

    def watch():
        c = g.controller
        if c.motion is not None:
            lag.append(float(np.max(np.abs(c.q_cmd_deg - c.q_motor_deg))))
        return g.done(cmd_id)

    assert g.run_until(watch, 30)
    c = g.controller
    assert max(lag) > 0.05  # the arm trails KAREL's path while it moves
    assert c.in_position() and c.completed >= 2
    s = g.status()
    np.testing.assert_allclose([float(s["x"]), float(s["y"]), float(s["z"])], TARGET[:3], atol=0.05)
    # the truth differs from the encoders' pose by the reducers' twist: small, not zero
    d = np.linalg.norm(g.true_pose_global()[:3, 3] - np.array(TARGET[:3]))
    assert 1e-3 < d < 2.0


def _bad_file(tmp_path, old, new):
    return spoiled(S400, tmp_path, old, new)


# Rows alike in shape only to test_plant_dynamics': the S400's file, its own keys.
@pytest.mark.parametrize("old, new, words", [
    ("link_mass_kg = [250.0,", "link_mass_kg = [-250.0,", ["link_mass_kg[0] = -250.0", "[0, 10000] kg"]),
    ("link_mass_kg = [250.0,", "link_mass_kg = [0.0,", ["link_mass_kg", "> 0"]),
    ("position_gain_per_s = [30.0,", "position_gain_per_s = [0.0,", ["position_gain_per_s", "> 0"]),
    ("velocity_feedforward = [0.0,", "velocity_feedforward = [1.5,", ["velocity_feedforward", "[0, 1]"]),
    ("servo_rate_hz = 1000.0", "servo_rate_hz = 100.0", ["velocity_bandwidth_hz", "servo_rate_hz"]),
    ("servo_rate_hz = 1000.0", "servo_rate_hz = 1000.0\nnotch_hz = 3", ["unknown", "notch_hz"]),
    ('servo_rate_hz = "assumed:', 'servo_rate_hz = "guess:', ["provenance", "servo_rate_hz"]),
])
def test_bad_axis_servo_or_dynamics_are_refused_naming_file_and_key(tmp_path, old, new, words):
    p = _bad_file(tmp_path, old, new)
    assert_refused(p, words)


def test_axis_servo_without_dynamics_is_refused(tmp_path):
    text = S400.read_text()
    cut = text.index("[dynamics]\n")
    end = text.index("[axis_servo]\n")
    p = tmp_path / "no_dyn.toml"
    p.write_text(text[:cut] + text[end:])
    with pytest.raises(RobotFileError, match=r"axis_servo.*dynamics"):
        load_robot(str(p))
