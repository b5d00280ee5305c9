"""The planner's pick (thesis eq. 4.15, pick_soln(), joint_to_act() limit checks)."""
from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from droid.kinematics import Unreachable, opw
from droid.kinematics.transforms import pose_to_T

START = (300.0, 100.0, 1340.0)  # thesis §6, start position (i), mm from the Reis base
ORIENTATIONS = {  # ZYZ deg of the WCP frame: tool pointing down, and the thesis's variants
    "down": (0.0, 180.0, 0.0),
    "down_yaw90": (90.0, 180.0, 0.0),
    "roll30": (90.0, 150.0, 0.0),
    "roll45": (90.0, 135.0, 0.0),
    "incline30": (0.0, 150.0, 0.0),
    "vertical": (0.0, 90.0, 0.0),
}


def _brute_force_pick(model, sols, prev):
    best, best_score = -1, np.inf
    for i, s in enumerate(sols):
        if np.isnan(s).any():
            continue
        if np.any(s < model.joint_min_deg) or np.any(s > model.joint_max_deg):
            continue
        c = model.gearing.joints_to_counts(s)
        if np.any(c < model.counts_min) or np.any(c > model.counts_max):
            continue
        score = float(np.sum(model.weights * np.abs(s - prev)))
        if score < best_score:
            best, best_score = i, score
    return best


def test_start_position_reachable_inside_limits(reis):
    t = pose_to_T(*START, *ORIENTATIONS["down"])
    q = reis.ik(t, np.zeros(6))
    assert reis.within_limits(q)
    assert np.allclose(reis.fk(q), t, atol=1e-7)
    assert np.allclose(q[:3], [18.434949, 21.586842, -15.518768], atol=1e-5)


@pytest.mark.parametrize("orientation", sorted(ORIENTATIONS))
def test_seam_tracking_workspace_inside_limits(reis, orientation):
    """x 100..500, y 0..300, z 1140..1540 mm around the start position has a solution inside the limits."""
    grid = np.array(list(itertools.product(np.linspace(100, 500, 5), np.linspace(0, 300, 4), np.linspace(1140, 1540, 5))))
    abc = ORIENTATIONS[orientation]
    ts = pose_to_T(grid[:, 0], grid[:, 1], grid[:, 2], *abc)
    sols = reis.ik_all_batch(ts)
    idx = reis.pick_batch(sols, np.zeros(6))
    assert np.all(idx >= 0), grid[idx < 0]
    for t in ts[::7]:
        q = reis.ik(t, np.zeros(6))
        assert np.allclose(reis.fk(q), t, atol=1e-7)


@pytest.mark.parametrize("robot", ["reis", "fanuc", "offset_robot"])
def test_pick_is_the_weighted_minimum(robot, request):
    model = request.getfixturevalue(robot)
    rng = np.random.default_rng(5)
    lo, hi = model.joint_min_deg, model.joint_max_deg
    checked = 0
    for _ in range(300):
        q = rng.uniform(lo, hi)
        prev = rng.uniform(lo, hi)
        t = model.fk(q)
        sols = model.ik_all(t, prev)
        expect = _brute_force_pick(model, sols, prev)
        got = model.pick_index(sols.tolist(), prev.tolist())
        assert got == expect
        assert model.pick_batch(sols[None], prev)[0] == expect
        if expect >= 0:
            checked += 1
            assert np.allclose(model.ik(t, prev), sols[expect])
    assert checked > 250


def test_pick_prefers_the_current_configuration(reis):
    q = np.array([10.0, 5.0, 20.0, 30.0, 40.0, 50.0])
    t = reis.fk(q)
    assert np.allclose(reis.ik(t, q), q, atol=1e-9)
    # from the flipped wrist, the flipped wrist is kept
    flipped = reis.ik_all(t, q)[1]
    assert reis.within_limits(flipped)
    assert np.allclose(reis.ik(t, flipped), flipped, atol=1e-9)


def test_weights_disfavour_joints_1_to_3(reis):
    """With k = (5,5,5,1,1,1), whenever the weighted pick differs from the unweighted one it moves joints 1-3 less."""
    assert np.all(reis.weights[:3] > reis.weights[3:])
    flat = dataclasses.replace(reis, weights=np.ones(6))
    rng = np.random.default_rng(17)
    differ = 0
    for _ in range(400):
        q = rng.uniform(reis.joint_min_deg, reis.joint_max_deg)
        prev = rng.uniform(reis.joint_min_deg, reis.joint_max_deg)
        sols = reis.ik_all(reis.fk(q), prev)
        iw = reis.pick_index(sols.tolist(), prev.tolist())
        jf = flat.pick_index(sols.tolist(), prev.tolist())
        if iw != jf:
            differ += 1
            arm = lambda i: np.abs(sols[i][:3] - prev[:3]).sum()  # noqa: E731
            assert arm(iw) < arm(jf)
    assert differ >= 5


def test_unreachable_out_of_reach(reis):
    with pytest.raises(Unreachable) as info:
        reis.ik(pose_to_T(5000.0, 0.0, 0.0, 0, 0, 0), np.zeros(6))
    assert isinstance(info.value, ValueError)
    assert "out of reach" in str(info.value)
    assert "\n" not in info.value.reason


def test_unreachable_outside_joint_limits(reis):
    # reachable, but only with joint 2 far outside its range (WCP low and behind the base)
    t = pose_to_T(-900.0, 0.0, 300.0, 0.0, 90.0, 0.0)
    sols = reis.ik_all(t)
    assert not np.isnan(sols).all()
    with pytest.raises(Unreachable) as info:
        reis.ik(t, np.zeros(6))
    assert "limits" in info.value.reason and "sol " in info.value.reason
    assert reis.pick_batch(sols[None], np.zeros(6))[0] == -1


def test_encoder_limits_are_checked_in_counts(reis):
    """joint_to_act() checks counts: a solution inside the joint limits but outside the encoder limits is dropped."""
    q = np.array([10.0, 5.0, 20.0, 30.0, 40.0, 50.0])
    t = reis.fk(q)
    counts = reis.gearing.joints_to_counts(q)
    cmax = reis.counts_max.copy()
    cmax[4] = int(counts[4]) - 1  # motor 5 may not reach this solution
    tight = dataclasses.replace(reis, counts_max=cmax)
    assert not tight._counts_implied
    assert reis.within_limits(q) and not tight.within_limits(q)
    assert "motor 5" in tight.limit_violation(q)
    sols = tight.ik_all(t, q)
    got = tight.ik(t, q) if tight.pick_index(sols.tolist(), q.tolist()) >= 0 else None
    if got is not None:
        assert not np.allclose(got, q)
        assert tight.gearing.joints_to_counts(got)[4] <= cmax[4]
    assert tight.pick_batch(sols[None], q)[0] == tight.pick_index(sols.tolist(), q.tolist())
    # forbid every motor-5 position: nothing left
    cmin5 = reis.counts_min.copy()
    cmin5[4] = 10**9 - 1
    cmax5 = reis.counts_max.copy()
    cmax5[4] = 10**9
    none = dataclasses.replace(reis, counts_min=cmin5, counts_max=cmax5)
    with pytest.raises(Unreachable, match="motor 5"):
        none.ik(t, q)


def test_ik_rejects_bad_previous_vector(reis):
    t = pose_to_T(*START, *ORIENTATIONS["down"])
    with pytest.raises(ValueError):
        reis.ik(t, [0, 0, 0])
    with pytest.raises(ValueError):
        reis.ik(t, [0, 0, float("nan"), 0, 0, 0])


def _fresh_pick(model, t, prev):
    """The pick without ik()'s memo: solve and pick from scratch."""
    rows = model._target_rows(t)
    sols = opw.ik(model.opw, rows, float(prev[0]), float(prev[3]))
    i = model.pick_index(sols, [float(v) for v in prev])
    return None if i < 0 else sols[i]


@pytest.mark.parametrize("singular", [False, True])
def test_ik_memo_gives_the_fresh_pick(reis, singular):
    """ik() keeps the last pose's solutions; asked again with another previous angle vector it must
    pick exactly as a fresh solve would -- also at the wrist singularity, where the solutions
    depend on the hint (joint 4) and are solved again."""
    model = dataclasses.replace(reis)  # a model of its own: an empty memo
    rng = np.random.default_rng(11)
    lo, hi = model.joint_min_deg, model.joint_max_deg
    for _ in range(200):
        q = rng.uniform(lo, hi)
        if singular:
            q[4] = 0.0
        t = model.fk(q)
        for prev in (rng.uniform(lo, hi), q + rng.normal(0, 1, 6), rng.uniform(lo, hi)):
            want = _fresh_pick(model, t, prev)
            if want is None:
                with pytest.raises(Unreachable):
                    model.ik(t, prev)
            else:
                assert model.ik(t, prev).tolist() == want


def test_ik_batch_equals_scalar_ik(reis):
    """RobotModel.ik_batch (chunked 8 solutions + pick) picks what ik picks, pose by pose."""
    rng = np.random.default_rng(17)
    n = 2500  # more than one chunk
    q = rng.uniform(reis.joint_min_deg * 0.9, reis.joint_max_deg * 0.9, (n, 6))
    ts = reis.fk_batch(q)
    prev = q + rng.normal(0.0, 2.0, q.shape)
    ts[5, :3, 3] = [5000.0, 0.0, 0.0]  # out of reach: NaN row, index -1
    got, idx = reis.ik_batch(ts, prev)
    assert got.shape == (n, 6) and idx.shape == (n,)
    assert idx[5] == -1 and np.isnan(got[5]).all()
    for i in range(0, n, 7):
        if i == 5:
            continue
        try:
            want = reis.ik(ts[i], prev[i])
        except Unreachable:
            assert idx[i] == -1
            continue
        assert np.allclose(got[i], want, atol=1e-9)
    with pytest.raises(ValueError):
        reis.ik_batch(ts[:3], np.zeros((2, 6)))
