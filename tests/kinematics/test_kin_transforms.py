"""Transforms and ZYZ Euler angles (thesis eq. 4.2, mat_inv_homo)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.kinematics.transforms import (
    R_to_zyz,
    T_to_pose,
    inv_homo,
    is_rigid,
    pose_to_T,
    rotx,
    roty,
    rotz,
    trans,
    wrap_deg,
    zyz_to_R,
)

angles = st.floats(-720.0, 720.0, allow_nan=False)
coords = st.floats(-5000.0, 5000.0, allow_nan=False)


def test_zyz_matches_eq_4_2_and_elementary_rotations():
    a, b, c = 30.0, 40.0, -75.0
    expect = (rotz(math.radians(a)) @ roty(math.radians(b)) @ rotz(math.radians(c)))[:3, :3]
    assert np.allclose(zyz_to_R(a, b, c), expect, atol=1e-15)
    # eq. 4.2 entries written out
    ca, sa, cb, sb, cc, sc = (f(math.radians(v)) for v in (a, b, c) for f in (math.cos, math.sin))
    r = zyz_to_R(a, b, c)
    assert r[0, 2] == pytest.approx(ca * sb)
    assert r[1, 2] == pytest.approx(sa * sb)
    assert r[2, 0] == pytest.approx(-sb * cc)
    assert r[2, 1] == pytest.approx(sb * sc)
    assert r[2, 2] == pytest.approx(cb)


def test_elementary_rotations_and_translation():
    assert np.allclose(rotx(math.pi / 2) @ [0, 1, 0, 1], [0, 0, 1, 1])
    assert np.allclose(roty(math.pi / 2) @ [0, 0, 1, 1], [1, 0, 0, 1])
    assert np.allclose(rotz(math.pi / 2) @ [1, 0, 0, 1], [0, 1, 0, 1])
    assert np.allclose(trans(1, 2, 3) @ [1, 1, 1, 1], [2, 3, 4, 1])


@settings(max_examples=300, deadline=None)
@given(angles, angles, angles)
def test_R_to_zyz_round_trip(a, b, c):
    r = zyz_to_R(a, b, c)
    abc = R_to_zyz(r)
    assert 0.0 <= abc[1] <= 180.0
    assert np.all(abc > -180.0) and np.all(abc <= 180.0)
    assert np.allclose(zyz_to_R(*abc), r, atol=1e-11, rtol=0)


def test_R_to_zyz_gimbal_lock_puts_rotation_into_c():
    for b in (0.0, 180.0):
        abc = R_to_zyz(zyz_to_R(25.0, b, 40.0))
        assert abc[0] == 0.0
        assert np.allclose(zyz_to_R(*abc), zyz_to_R(25.0, b, 40.0), atol=1e-14)
    assert R_to_zyz(zyz_to_R(25.0, 0.0, 40.0))[2] == pytest.approx(65.0)


@settings(max_examples=200, deadline=None)
@given(coords, coords, coords, angles, angles, angles)
def test_pose_round_trip_and_inverse(x, y, z, a, b, c):
    t = pose_to_T(x, y, z, a, b, c)
    assert is_rigid(t)
    assert np.allclose(pose_to_T(*T_to_pose(t)), t, atol=1e-9)
    assert np.allclose(inv_homo(t) @ t, np.eye(4), atol=1e-9)
    assert np.allclose(inv_homo(t), np.linalg.inv(t), atol=1e-9)


def test_batched_forms_match_single():
    rng = np.random.default_rng(3)
    poses = rng.uniform(-500, 500, (20, 6))
    ts = pose_to_T(*poses.T)
    assert ts.shape == (20, 4, 4)
    for p, t in zip(poses, ts):
        assert np.array_equal(pose_to_T(*p), t)
    assert np.allclose(T_to_pose(ts), np.array([T_to_pose(t) for t in ts]))
    assert np.allclose(inv_homo(ts) @ ts, np.eye(4), atol=1e-9)


@settings(max_examples=500, deadline=None)
@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_range_and_congruence(x):
    w = wrap_deg(x)
    assert -180.0 < w <= 180.0
    assert math.isclose(math.remainder(w - x, 360.0), 0.0, abs_tol=1e-9)
    wa = wrap_deg(np.array([x, -x]))
    assert np.all(wa > -180.0) and np.all(wa <= 180.0)
    assert abs(math.remainder(wa[0] - x, 360.0)) < 1e-6


def test_wrap_edges():
    assert wrap_deg(-180.0) == 180.0
    assert wrap_deg(180.0) == 180.0
    assert wrap_deg(540.0) == 180.0
    assert list(wrap_deg(np.array([-180.0, 180.0, -540.0, 359.0]))) == [180.0, 180.0, 180.0, -1.0]


def test_is_rigid_rejects_bad_matrices():
    t = pose_to_T(1, 2, 3, 10, 20, 30)
    assert is_rigid(t)
    bad = t.copy()
    bad[0, 0] *= 1.1
    assert not is_rigid(bad)
    mirror = t.copy()
    mirror[:3, 0] *= -1  # determinant -1
    assert not is_rigid(mirror)
    nan = t.copy()
    nan[0, 3] = np.nan
    assert not is_rigid(nan)
