"""The Reis's static drive deflection as plus mode models it (droid.tasks.seam.compliance)
against the plant twin's own static load (droid.sim.reis.plant) -- the same robot file."""
import dataclasses

import numpy as np
import pytest

from droid.kinematics import load_robot
from droid.sim.reis.plant import ReisPlant
from droid.tasks.seam.compliance import StaticDeflection

POSES = [[18.4, 21.9, -23.6, -89.3, 71.5, -1.8], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
         [30.0, 40.0, -10.0, 20.0, 50.0, 60.0], [-45.0, -20.0, 35.0, 90.0, -30.0, 10.0]]


@pytest.mark.parametrize("q", POSES)
def test_the_static_torques_are_the_plants(q):
    sd = StaticDeflection(load_robot("reis_v15"))
    assert np.allclose(sd.torque_nm(q), ReisPlant().gravity_joint_torque_nm(q), atol=1e-6)


@pytest.mark.parametrize("q", POSES)
def test_link_and_motor_angles_invert_each_other_and_sag_by_torque_over_stiffness(q):
    model = load_robot("reis_v15")
    sd = StaticDeflection(model)
    q_link = sd.link_deg(q)
    k = model.dynamics.hd_stiffness_nm_per_rad
    tau_home = sd.torque_nm(model.home_switch_deg)  # homing on link-side switches absorbs that
    assert np.allclose(q_link - q, np.degrees((sd.torque_nm(q) - tau_home) / k))
    assert np.max(np.abs(q_link - q)) <= 0.3  # catalogue stiffness: tenths of a degree
    assert np.allclose(sd.motor_deg(q_link), q, atol=1e-5)


def test_a_robot_file_without_dynamics_gives_no_correction():
    model = dataclasses.replace(load_robot("reis_v15"), dynamics=None)
    sd = StaticDeflection(model)
    assert not sd.active
    assert np.array_equal(sd.link_deg(POSES[0]), np.array(POSES[0]))
