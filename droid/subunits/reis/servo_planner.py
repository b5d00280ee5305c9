"""The servo planner's pure functions (thesis §4.1.5.2) and the braking profile (§4.1.5.1).

All positions are integer encoder counts, velocities counts per servo tick,
accelerations counts per tick squared; arrays are per joint (shape (6,)) and
way-point arrays are (n, 6).

Time inside a command period is kept exactly as integers: the period is
``period_num / period_den`` servo ticks (500 Hz / 60 Hz = 25/3 ticks) and a
period starting at servo time ``start_sub / period_den`` covers the servo
ticks k with ``start_sub < k*period_den <= start_sub + period_num`` (8 or 9
of them).  With ``period_den = 1`` this is the thesis's ramp of
``period_num`` (8) steps.
"""
from __future__ import annotations

import numpy as np


def max_reach_counts(max_counts_per_tick, period_num: int, period_den: int = 1) -> np.ndarray:
    """Largest move [counts] per command period that keeps every tick at or
    below ``max_counts_per_tick`` (floor of max * period)."""
    return (np.asarray(max_counts_per_tick, np.int64) * period_num) // period_den


def limit_target(origin, target, max_counts_per_tick, period_num: int, period_den: int = 1) -> np.ndarray:
    """Clip ``target`` [counts] to the joint's maximum speed (thesis: "limited by
    the maximum allowable speed for the given joint to become the actual target")."""
    origin = np.asarray(origin, np.int64)
    reach = max_reach_counts(max_counts_per_tick, period_num, period_den)
    return np.clip(np.asarray(target, np.int64), origin - reach, origin + reach)


def ramp_ticks(start_sub: int, period_num: int, period_den: int = 1) -> tuple[int, int]:
    """First and last servo tick (inclusive) inside the period starting at
    ``start_sub`` [1/period_den ticks]."""
    first = start_sub // period_den + 1
    last = (start_sub + period_num) // period_den
    return first, last


def linear_ramp(
    origin, target, period_num: int, period_den: int = 1, start_sub: int = 0, first_tick: int | None = None
) -> np.ndarray:
    """Way-points [counts, int64, (n, 6)] of the linear ramp origin -> target.

    Way-point at servo tick k is ``origin + floor(diff * (k*den - start_sub) / num)``
    for the ticks of the period (from ``first_tick`` on, if given: the ticks
    before it were already spent).  Consecutive way-points differ by at most
    ceil(|diff| * den / num) counts, positions are computed from the end points
    (no accumulated rounding), and a period ending on a tick ends exactly on
    ``target`` -- with ``period_den = 1`` always, as in the thesis ("the final
    value in the queue guarantees that the cache remains on target").
    """
    origin = np.asarray(origin, np.int64)
    diff = np.asarray(target, np.int64) - origin
    first, last = ramp_ticks(start_sub, period_num, period_den)
    if first_tick is not None:
        first = max(first, first_tick)
    k = np.arange(first, last + 1, dtype=np.int64)[:, None]
    return origin + (diff * (k * period_den - start_sub)) // period_num


def braking_profile(position, velocity, decel_counts_per_tick2, steps: int):
    """Emergency braking (§4.1.4, §4.1.5.1): decelerate from ``velocity``
    [counts/tick] to zero at ``decel_counts_per_tick2``, then hold.

    ``position`` and ``velocity`` are float arrays (the exact braking state);
    returns (way-points [counts, int64, (steps, 6)], final position, final
    velocity) so a longer stop continues exactly in the next queue load.
    """
    pos = np.array(position, float)
    vel = np.array(velocity, float)
    decel = np.asarray(decel_counts_per_tick2, float)
    out = np.empty((steps, pos.shape[0]), np.int64)
    for i in range(steps):
        speed = np.maximum(np.abs(vel) - decel, 0.0)
        vel = np.sign(vel) * speed
        pos = pos + vel
        out[i] = np.rint(pos)
    return out, pos, vel


def braking_distance_counts(velocity, decel_counts_per_tick2) -> np.ndarray:
    """Distance [counts] :func:`braking_profile` covers from ``velocity`` until stopped."""
    v = np.abs(np.asarray(velocity, float))
    a = np.asarray(decel_counts_per_tick2, float)
    n = np.floor(v / a)  # ticks with non-zero speed after the first decrement
    return n * v - a * n * (n + 1) / 2.0


def braking_ticks(velocity, decel_counts_per_tick2) -> np.ndarray:
    """Ticks until :func:`braking_profile` reaches zero speed from ``velocity``."""
    return np.ceil(np.abs(np.asarray(velocity, float)) / np.asarray(decel_counts_per_tick2, float))
