"""Servo planner ramps and the braking profile (thesis §4.1.5.1-4.1.5.2), as properties."""
from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from droid.subunits.reis.servo_planner import (
    braking_distance_counts,
    braking_profile,
    braking_ticks,
    limit_target,
    linear_ramp,
    max_reach_counts,
    ramp_ticks,
)

counts = st.integers(-2_000_000, 2_000_000)
six = st.lists(counts, min_size=6, max_size=6).map(np.array)
speeds = st.lists(st.integers(1, 600), min_size=6, max_size=6).map(np.array)
periods = st.sampled_from([(8, 1), (25, 3), (9, 1), (50, 6), (17, 2), (1, 1)])


@given(six, six, speeds)
def test_thesis_ramp_ends_on_target_and_respects_max_speed(origin, target, vmax):
    goal = limit_target(origin, target, vmax, 8)
    ramp = linear_ramp(origin, goal, 8)
    assert ramp.shape == (8, 6)
    assert np.array_equal(ramp[-1], goal)  # "the cache remains on target"
    steps = np.diff(np.vstack([origin, ramp]), axis=0)
    assert np.all(np.abs(steps) <= vmax)
    assert np.all(steps * np.sign(goal - origin) >= 0)  # monotone, no overshoot
    assert np.all(np.abs(steps).max(axis=0) - np.abs(steps).min(axis=0) <= 1)  # linear


@given(six, six, speeds)
def test_speed_limit_only_clips_what_is_too_fast(origin, target, vmax):
    goal = limit_target(origin, target, vmax, 8)
    fast = np.abs(target - origin) > 8 * vmax
    assert np.array_equal(goal[~fast], target[~fast])
    assert np.array_equal(np.abs(goal - origin)[fast], 8 * vmax[fast])


@given(six, six, speeds, periods, st.integers(0, 10_000))
def test_phased_ramps_chain_without_drift_or_speeding(origin, target, vmax, period, start):
    """Consecutive command periods (8.33 ticks at 500/60 Hz) tile the tick line exactly."""
    num, den = period
    goal = limit_target(origin, target, vmax, num, den)
    first, last = ramp_ticks(start, num, den)
    ramp = linear_ramp(origin, goal, num, den, start)
    assert len(ramp) == last - first + 1
    assert (start + num) // den - start // den == len(ramp)  # ticks tile exactly
    previous_end = np.asarray(origin) + (np.asarray(goal - origin) * (first * den - den - start)) // num
    steps = np.diff(np.vstack([previous_end if first * den - den > start else origin, ramp]), axis=0)
    assert np.all(np.abs(steps) <= vmax)
    if (start + num) % den == 0:
        assert np.array_equal(ramp[-1], goal)
    else:  # a tick short of the period end: within one tick's motion of the goal
        assert np.all(np.abs(goal - ramp[-1]) <= np.abs(goal - origin) * den // num + 1)
    nxt = linear_ramp(goal, goal, num, den, start + num)
    assert np.all(nxt == goal)  # holding a target stays exactly on it


@given(six, six, st.integers(0, 100), periods)
def test_late_first_tick_skips_only_spent_way_points(origin, target, late, period):
    num, den = period
    full = linear_ramp(origin, target, num, den, 0)
    first, _ = ramp_ticks(0, num, den)
    part = linear_ramp(origin, target, num, den, 0, first_tick=first + late)
    assert np.array_equal(part, full[late:])


def test_reach_for_500_over_60():
    assert np.array_equal(max_reach_counts([222, 444], 25, 3), [1850, 3700])


@given(
    st.lists(st.integers(-500, 500), min_size=6, max_size=6).map(np.array),
    st.lists(st.sampled_from([1.0, 2.0, 3.5, 4.0]), min_size=6, max_size=6).map(np.array),
)
def test_braking_stops_within_its_time_and_distance_then_holds(v0, decel):
    pos = np.zeros(6)
    n = int(braking_ticks(v0, decel).max()) + 8
    way, end, vel = braking_profile(pos, v0.astype(float), decel, n)
    assert np.all(vel == 0)
    travel = np.vstack([np.zeros(6), way])
    speed = np.abs(np.diff(travel, axis=0))
    assert np.all(speed <= np.abs(v0) + 1)  # never faster than at the start
    stop = braking_ticks(v0, decel).astype(int)
    for j in range(6):
        assert np.all(way[stop[j]:, j] == way[-1, j])  # holds once stopped
        assert np.all(np.sign(way[:, j]) * np.sign(v0[j]) >= 0)  # never reverses
    assert np.allclose(np.abs(end), braking_distance_counts(v0, decel))


def test_braking_continues_exactly_across_queue_loads():
    v0, decel = np.full(6, 150.0), np.full(6, 2.0)
    one, _, _ = braking_profile(np.zeros(6), v0, decel, 80)
    a, pos, vel = braking_profile(np.zeros(6), v0, decel, 8)
    parts = [a]
    for _ in range(9):
        b, pos, vel = braking_profile(pos, vel, decel, 8)
        parts.append(b)
    assert np.array_equal(np.vstack(parts)[:80], one)
