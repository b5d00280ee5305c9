"""Analytic inverse kinematics (thesis §4.1.1.2, cart_to_joint()): 8 solutions, round trips, singularities."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.kinematics.transforms import pose_to_T
from helpers_kin import REIS_TABLE, angle_diff_deg, dh_product

TOL = 1e-7  # mm and rotation-matrix entries


def assert_same_solutions(a, b, atol_deg):
    """Same NaN rows and the same angles modulo 360 (180 and -179.99999999999997 are equal)."""
    a, b = np.asarray(a), np.asarray(b)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    assert np.all(np.abs(angle_diff_deg(a[ok], b[ok])) <= atol_deg)


def _well_conditioned(model, q, t) -> bool:
    """Away from the wrist, elbow and shoulder singularities the original q is recoverable to 1e-6 deg."""
    from droid.kinematics.opw import RAD

    p = model.opw
    q5 = (p.signs[4] * q[4] - p.offsets_deg[4]) * RAD
    q3 = (p.signs[2] * q[2] - p.offsets_deg[2]) * RAD + p._psi3
    return abs(np.sin(q5)) > 1e-3 and abs(np.sin(q3)) > 1e-3 and np.hypot(t[0, 3], t[1, 3]) > abs(p.b) + 1e-3


def _round_trip(model, q):
    t = model.fk(q)
    sols = model.ik_all(t, q)
    assert sols.shape == (8, 6)
    valid = ~np.isnan(sols).any(axis=1)
    assert valid.any()
    for s in sols[valid]:
        assert np.all(s > -180.0) and np.all(s <= 180.0)
        assert np.max(np.abs(model.fk(s) - t)) <= TOL
    # the joint vector we started from is one of the solutions (mod 360)
    if _well_conditioned(model, q, t):
        d = np.abs(angle_diff_deg(sols[valid], q)).max(axis=1)
        assert d.min() < 1e-6
    return sols


@pytest.mark.parametrize("robot", ["reis", "fanuc", "offset_robot"])
def test_seeded_round_trip_every_solution(robot, request):
    model = request.getfixturevalue(robot)
    rng = np.random.default_rng(2024)
    for q in rng.uniform(-180.0, 180.0, (400, 6)):
        _round_trip(model, q)


def test_reis_solutions_reproduce_the_thesis_dh_chain(reis):
    rng = np.random.default_rng(7)
    for q in rng.uniform(-180.0, 180.0, (50, 6)):
        t = dh_product(REIS_TABLE, q)
        for s in reis.ik_all(t):
            if not np.isnan(s).any():
                assert np.max(np.abs(dh_product(REIS_TABLE, s) - t)) <= TOL


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-179.9, 180.0, allow_nan=False), min_size=6, max_size=6))
def test_property_round_trip(q):
    from droid.kinematics import load_robot

    _round_trip(load_robot("reis_v15"), np.array(q))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40))
def test_property_batch_equals_single(seed, n):
    from droid.kinematics import load_robot

    model = load_robot("reis_v15")
    rng = np.random.default_rng(seed)
    q = rng.uniform(-180.0, 180.0, (n, 6))
    poses = model.fk_batch(q)
    # add unreachable poses too
    far = poses.copy()
    far[:, :3, 3] *= 3.0
    ts = np.concatenate([poses, far])
    hint = rng.uniform(-180.0, 180.0, (2 * n, 6))
    batch = model.ik_all_batch(ts, hint)
    assert batch.shape == (2 * n, 8, 6)
    for t, h, b in zip(ts, hint, batch):
        assert_same_solutions(model.ik_all(t, h), b, 1e-9)


def test_batch_large_chunked(reis):
    rng = np.random.default_rng(9)
    q = rng.uniform(-180.0, 180.0, (3000, 6))
    batch = reis.ik_all_batch(reis.fk_batch(q))
    for i in (0, 1023, 1024, 2999):
        assert_same_solutions(batch[i], reis.ik_all(reis.fk(q[i])), 1e-9)


def test_solution_numbering_matches_thesis_branches(reis):
    """index = 4*shoulder + 2*elbow + wrist: d2 > 0, Ds = cos(theta3) > 0, Rr > 0 (theta5 > 0)."""
    rng = np.random.default_rng(11)
    for q in rng.uniform(-180.0, 180.0, (100, 6)):
        t = reis.fk(q)
        sols = reis.ik_all(t)
        x, y = t[0, 3], t[1, 3]
        for i, s in enumerate(sols):
            if np.isnan(s).any():
                continue
            shoulder, elbow, wrist = i >> 2, (i >> 1) & 1, i & 1
            th1, th3, th5 = np.radians(s[0]), np.radians(s[2]), s[4]
            front = np.cos(th1) * x + np.sin(th1) * y
            assert (front >= -1e-9) if shoulder == 0 else (front <= 1e-9)
            assert (np.cos(th3) >= -1e-12) if elbow == 0 else (np.cos(th3) <= 1e-12)
            assert (th5 >= 0.0) if wrist == 0 else (th5 <= 0.0)


def test_unreachable_gives_eight_nan_rows(reis):
    t = pose_to_T(3000.0, 0.0, 725.0, 0.0, 90.0, 0.0)
    sols = reis.ik_all(t)
    assert sols.shape == (8, 6) and np.isnan(sols).all()
    assert np.isnan(reis.ik_all_batch(t[None])).all()


def test_ik_rejects_non_finite_target(reis):
    t = pose_to_T(300.0, 0.0, 1000.0, 0.0, 90.0, 0.0)
    t[0, 3] = np.inf
    with pytest.raises(ValueError):
        reis.ik_all(t)
    with pytest.raises(ValueError):
        reis.ik_all_batch(t[None])
    with pytest.raises(ValueError):
        reis.ik_all(np.eye(3))


# ---------------------------------------------------------------- singularities


def test_wrist_singularity_keeps_joint4_and_rotates_joint6(reis):
    q = np.array([20.0, 10.0, 30.0, 50.0, 0.0, 40.0])  # theta5 = 0: joints 4 and 6 aligned
    t = reis.fk(q)
    for hint4 in (0.0, 50.0, -120.0):
        sols = reis.ik_all(t, [0, 0, 0, hint4, 0, 0])
        for s in sols[~np.isnan(sols).any(axis=1)]:
            assert np.max(np.abs(reis.fk(s) - t)) <= TOL
            if abs(s[4]) < 1e-6:  # the singular branches
                assert s[3] == pytest.approx(hint4, abs=1e-9)
        # the branch that has q1..q3 of q reproduces q4 + q6 = 90 through joint 6 alone
        s0 = sols[0]
        assert s0[4] == pytest.approx(0.0, abs=1e-9)
        assert angle_diff_deg(s0[3] + s0[5], 90.0) == pytest.approx(0.0, abs=1e-9)
    batch = reis.ik_all_batch(t[None], [0, 0, 0, 50.0, 0, 0])
    assert np.allclose(batch[0], reis.ik_all(t, [0, 0, 0, 50.0, 0, 0]), atol=1e-9, equal_nan=True)


def test_wrist_singularity_flipped(reis):
    """theta5 = 180 deg (wrist axes anti-parallel) is singular too."""
    q = np.array([0.0, 0.0, 0.0, 30.0, 180.0, 20.0])
    t = reis.fk(q)
    sols = reis.ik_all(t, [0, 0, 0, 30.0, 0, 0])
    for s in sols[~np.isnan(sols).any(axis=1)]:
        assert np.max(np.abs(reis.fk(s) - t)) <= TOL


def test_shoulder_singularity_uses_previous_joint1(reis):
    # WCP on the joint-1 axis: theta2 = 0, theta3 = 90 (forearm straight up)
    q = np.array([35.0, 0.0, 90.0, 10.0, 30.0, 0.0])
    t = reis.fk(q)
    assert np.hypot(t[0, 3], t[1, 3]) < 1e-9
    for hint1 in (0.0, 35.0, -100.0):
        sols = reis.ik_all(t, [hint1, 0, 0, 0, 0, 0])
        valid = ~np.isnan(sols).any(axis=1)
        assert valid.all()
        assert np.allclose(sols[:4, 0], hint1)
        assert np.allclose(angle_diff_deg(sols[4:, 0], hint1 + 180.0), 0.0)
        for s in sols:
            assert np.max(np.abs(reis.fk(s) - t)) <= TOL
    used = np.zeros(1, bool)
    reis.ik_all_batch(t[None], [35.0, 0, 0, 0, 0, 0], hint_used=used)
    assert used[0]


def test_elbow_singularity_stretched_arm(reis):
    # theta3 = 90: forearm in line with the upper arm, |D| = 1, elbow branches coincide
    q = np.array([10.0, -30.0, 90.0, 20.0, 40.0, 60.0])
    t = reis.fk(q)
    sols = reis.ik_all(t)
    assert not np.isnan(sols[:2]).any()
    assert np.allclose(sols[0], sols[2], atol=1e-4)  # elbow 0 == elbow 1 (acos near 1 is ill-conditioned)
    for s in sols[~np.isnan(sols).any(axis=1)]:
        assert np.max(np.abs(reis.fk(s) - t)) <= TOL
    # 1 micrometre beyond the stretched reach: no solution
    wcp = t[:3, 3] - np.array([0, 0, 725.0])
    far = t.copy()
    far[:3, 3] = np.array([0, 0, 725.0]) + wcp * (1 + 1e-3 / np.linalg.norm(wcp))
    assert np.isnan(reis.ik_all(far)).all()


def test_folded_arm(reis):
    # theta3 = -90: forearm folded back along the upper arm (the other |D| = 1 end)
    q = np.array([0.0, 20.0, -90.0, 0.0, 60.0, 0.0])
    t = reis.fk(q)
    sols = reis.ik_all(t)
    assert not np.isnan(sols).all()
    for s in sols[~np.isnan(sols).any(axis=1)]:
        assert np.max(np.abs(reis.fk(s) - t)) <= TOL


def test_ik_rejects_a_target_that_is_not_a_rotation(reis):
    t = pose_to_T(300.0, 0.0, 1000.0, 10.0, 90.0, 20.0)
    for bad in (np.diag([1.0, 1.0, -1.0, 1.0]) @ t, t * np.array([[1.01], [1], [1], [1]])):
        with pytest.raises(ValueError, match="rotation"):
            reis.ik_all(bad)
        with pytest.raises(ValueError, match="rotation"):
            reis.ik(bad, np.zeros(6))
        with pytest.raises(ValueError, match="pose 1: rotation"):
            reis.ik_all_batch(np.stack([t, bad]))
    # float32 round-off is accepted
    assert not np.isnan(reis.ik_all(t.astype(np.float32).astype(float))).all()


@pytest.mark.parametrize("robot", ["reis", "fanuc", "offset_robot"])
def test_round_trip_on_special_angles(robot, request):
    """Every combination of singular and boundary angles round-trips (scalar and batched agree)."""
    import itertools

    model = request.getfixturevalue(robot)
    special = [0.0, 90.0, -90.0, 180.0, 1e-9, -1e-9, 89.999999, 30.0]
    qs = np.array([[a, b, c, d, e, f] for a, b, c in itertools.product([0.0, 180.0, -45.0], special, special)
                   for d, e, f in [(0.0, 0.0, 0.0), (30.0, 180.0, -30.0), (90.0, 1e-9, 0.0), (-170.0, 90.0, 180.0)]])
    ts = model.fk_batch(qs)
    batch = model.ik_all_batch(ts, qs)
    for q, t, b in zip(qs, ts, batch):
        sols = _round_trip(model, q)
        # near (not at) the wrist singularity q4/q6 are ill-conditioned: ~1e-16 / sin(q5) rad
        assert_same_solutions(sols, b, 1e-5)
        for s in b[~np.isnan(b).any(axis=1)]:
            assert np.max(np.abs(model.fk(s) - t)) <= TOL
