"""The ABB IRB 2400/10 robot file (issue 26): FK against an independent chain, the 8-solution IK,
FK -> IK -> FK round trips.

The independent check is the method of the Reis's (test_kin_fk.py): the arm's D-H chain written
out again here, by hand, from the published OPW parameters (opw_kinematics' makeIrb2400_10) and
ABB's joint conventions, multiplied with helpers_kin.dh_product -- not the robot file's tables,
not droid.kinematics.  A second, separate anchor: ABB's tool0 at the calibration position
(all joints 0) lies at x = a1 + c3 + c4 = 940, z = c1 + c2 + |a2| = 1455 mm, facing +x with its
x axis down (ABB's orientation quaternion [0.7071, 0, 0.7071, 0] for a jointtarget of zeros).
"""
from __future__ import annotations

import numpy as np
import pytest

from droid.kinematics import load_robot
from helpers_kin import angle_diff_deg, dh_product

TOL = 1e-7  # mm and rotation-matrix entries

# (theta offset deg, d mm, a mm, alpha deg), from a1 100, a2 -135, c1 615, c2 705, c3 755, c4 85.
IRB2400_TABLE = [
    (0.0, 615.0, 100.0, -90.0),
    (-90.0, 0.0, 705.0, 0.0),
    (0.0, 0.0, 135.0, -90.0),
    (0.0, 755.0, 0.0, 90.0),
    (0.0, 0.0, 0.0, -90.0),
    (180.0, 85.0, 0.0, 0.0),
]


@pytest.fixture(scope="module")
def abb():
    return load_robot("abb_irb2400")


def test_abb_fk_matches_an_independent_dh_chain(abb):
    rng = np.random.default_rng(2600)
    for q in rng.uniform(-180.0, 180.0, (300, 6)):
        assert np.allclose(abb.fk(q), dh_product(IRB2400_TABLE, q), atol=1e-9, rtol=0)


def test_abb_calibration_pose_is_abbs_tool0():
    t = dh_product(IRB2400_TABLE, np.zeros(6))
    assert np.allclose(t[:3, 3], [940.0, 0.0, 1455.0], atol=1e-9)
    assert np.allclose(t[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)  # flange faces +x
    assert np.allclose(t[:3, 0], [0.0, 0.0, -1.0], atol=1e-12)  # tool0 x points down
    model = load_robot("abb_irb2400")
    assert np.allclose(model.fk(np.zeros(6)), t, atol=1e-9)


def test_abb_joint_directions_are_abbs():
    """Axes 2, 3 and 5 positive move forward / down; axis 1 positive turns counter-clockwise."""
    z0 = dh_product(IRB2400_TABLE, np.zeros(6))[:3, 3]
    assert dh_product(IRB2400_TABLE, [0, 10, 0, 0, 0, 0])[0, 3] > z0[0]  # upper arm leans forward
    assert dh_product(IRB2400_TABLE, [0, 0, 10, 0, 0, 0])[2, 3] < z0[2]  # forearm down
    assert dh_product(IRB2400_TABLE, [0, 0, 0, 0, 10, 0])[2, 2] < 0  # flange tilts down
    assert dh_product(IRB2400_TABLE, [10, 0, 0, 0, 0, 0])[1, 3] > 0  # counter-clockwise


def test_abb_every_ik_solution_reproduces_the_independent_chain(abb):
    rng = np.random.default_rng(2601)
    n_valid = 0
    for q in rng.uniform(-180.0, 180.0, (300, 6)):
        t = dh_product(IRB2400_TABLE, q)
        sols = abb.ik_all(t)
        assert sols.shape == (8, 6)
        for s in sols:
            if not np.isnan(s).any():
                n_valid += 1
                assert np.max(np.abs(dh_product(IRB2400_TABLE, s) - t)) <= TOL
    assert n_valid >= 300 * 4  # an OPW arm with a1 > 0 has 4..8 solutions for a reachable pose


def test_abb_round_trip_fk_ik_fk_recovers_the_joints(abb):
    """FK -> IK -> FK inside the working range: the start joints are one of the 8 solutions, and
    the planner's pick (nearest to the start) returns them."""
    rng = np.random.default_rng(2602)
    lo, hi = abb.joint_min_deg, abb.joint_max_deg
    checked = 0
    for q in rng.uniform(np.maximum(lo, -179.0), np.minimum(hi, 179.0), (300, 6)):
        if abs(np.sin(np.radians(q[4]))) < 1e-2:
            continue  # wrist singularity: joints 4 and 6 are not separable
        t = abb.fk(q)
        sols = abb.ik_all(t, q)
        valid = ~np.isnan(sols).any(axis=1)
        d = np.abs(angle_diff_deg(sols[valid], q)).max(axis=1)
        assert d.min() < 1e-6
        for s in sols[valid]:
            assert np.max(np.abs(abb.fk(s) - t)) <= TOL
        picked = abb.ik(t, q)
        assert np.max(np.abs(angle_diff_deg(picked, q))) < 1e-6
        checked += 1
    assert checked > 250


def test_abb_limits_and_gearing(abb):
    assert abb.joint_min_deg.tolist() == [-180, -100, -60, -200, -120, -400]
    assert abb.joint_max_deg.tolist() == [180, 110, 65, 200, 120, 400]
    assert abb.vmax_deg_s.tolist() == [150, 150, 150, 360, 360, 450]
    assert abb.dynamics is not None and abb.axis_servo is not None
    # a count is well below EGM's 0.01 deg goal on every joint
    per_count = 1.0 / abb.gearing.joints_to_counts(np.eye(6)).diagonal()
    assert np.all(np.abs(per_count) < 0.002)
    # counts round-trip exactly enough through the gearing for the whole range
    q = np.array([179.9, -99.0, 64.0, 199.0, -119.0, 399.0])
    assert np.allclose(abb.gearing.counts_to_joints(abb.gearing.joints_to_counts(q)), q, atol=1e-9)
