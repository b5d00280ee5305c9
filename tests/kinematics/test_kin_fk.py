"""Forward kinematics (thesis eq. 4.1-4.2) against an independent D-H product."""
from __future__ import annotations

import numpy as np
import pytest

from droid.kinematics.transforms import pose_to_T
from helpers_kin import REIS_TABLE, dh_product


def test_reis_fk_matches_thesis_dh_product(reis):
    rng = np.random.default_rng(41)
    for q in rng.uniform(-180.0, 180.0, (300, 6)):
        assert np.allclose(reis.fk(q), dh_product(REIS_TABLE, q), atol=1e-9, rtol=0)


def test_fanuc_fk_matches_its_dh_table(fanuc):
    table = list(zip(fanuc.dh.theta_offset_deg, fanuc.dh.d_mm, fanuc.dh.a_mm, fanuc.dh.alpha_deg))
    rng = np.random.default_rng(42)
    for q in rng.uniform(-180.0, 180.0, (100, 6)):
        assert np.allclose(fanuc.fk(q), dh_product(table, q), atol=1e-9, rtol=0)
        assert np.allclose(fanuc.fk(q), fanuc.fk_dh(q), atol=1e-9, rtol=0)


def test_reis_zero_pose_geometry(reis):
    t = reis.fk([0, 0, 0, 0, 0, 0])
    # upper arm vertical (d1 + l2 = 1325 mm), forearm d4 = 540 mm along +x, tool z along +x
    assert np.allclose(t[:3, 3], [540.0, 0.0, 1325.0], atol=1e-12)
    assert np.allclose(t[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)
    assert np.allclose(t[3], [0, 0, 0, 1])
    # joint 2 + 90 deg tips the upper arm backwards (thesis theta2 sign): WCP behind and low
    t = reis.fk([0, 90, 0, 0, 0, 0])
    assert np.allclose(t[:3, 3], [-600.0, 0.0, 725.0 + 540.0], atol=1e-9)


def test_fk_batch_matches_single(reis, offset_robot):
    rng = np.random.default_rng(43)
    q = rng.uniform(-180.0, 180.0, (50, 6))
    for model in (reis, offset_robot):
        tb = model.fk_batch(q)
        assert tb.shape == (50, 4, 4)
        for qi, ti in zip(q, tb):
            assert np.allclose(model.fk(qi), ti, atol=1e-9)


def test_base_transform(reis):
    base = pose_to_T(1000.0, -200.0, 50.0, 90.0, 0.0, 0.0)
    moved = reis.with_base(base)
    assert np.array_equal(reis.base, np.eye(4))  # original unchanged
    rng = np.random.default_rng(44)
    for q in rng.uniform(-150.0, 150.0, (20, 6)):
        assert np.allclose(moved.fk(q), base @ reis.fk(q), atol=1e-9)
        assert np.allclose(moved.fk_batch(q[None])[0], base @ reis.fk(q), atol=1e-9)
        # ik in the world frame: same joint solutions as the robot-frame target
        sols_world = moved.ik_all(moved.fk(q), q)
        sols_robot = reis.ik_all(reis.fk(q), q)
        assert np.allclose(sols_world, sols_robot, atol=1e-7, equal_nan=True)
    with pytest.raises(ValueError):
        reis.with_base(np.diag([2.0, 1.0, 1.0, 1.0]))


def test_fk_rejects_wrong_arity(reis):
    with pytest.raises(ValueError):
        reis.fk([0, 0, 0])
    with pytest.raises(ValueError):
        reis.fk_batch(np.zeros((3, 5)))
