"""The servo planner's pure functions (thesis §4.1.5.2) and the braking profile (§4.1.5.1).

All positions are integer encoder counts, velocities counts per servo tick,
accelerations counts per tick squared; arrays are per joint (shape (6,)) and
the queue is (steps, 6).
"""
from __future__ import annotations

import numpy as np


def limit_target(origin, target, max_counts_per_tick, steps: int) -> np.ndarray:
    """Clip ``target`` [counts] so a ramp of ``steps`` ticks from ``origin`` never
    exceeds ``max_counts_per_tick``: |target - origin| <= steps * max (thesis:
    "limited by the maximum allowable speed for the given joint")."""
    origin = np.asarray(origin, np.int64)
    reach = np.asarray(max_counts_per_tick, np.int64) * steps
    return np.clip(np.asarray(target, np.int64), origin - reach, origin + reach)


def linear_ramp(origin, target, steps: int) -> np.ndarray:
    """``steps`` way-points [counts] from ``origin`` (exclusive) to ``target`` (inclusive).

    Way-point k (1-based) is origin + floor((target - origin) * k / steps): the
    per-tick increments differ by at most one count, none exceeds
    ceil(|target - origin| / steps), and the last way-point is exactly the
    target, so the cache "remains on target" (§4.1.5.2).
    """
    origin = np.asarray(origin, np.int64)
    diff = np.asarray(target, np.int64) - origin
    k = np.arange(1, steps + 1, dtype=np.int64)[:, None]
    return origin + (diff * k) // steps


def braking_profile(position, velocity, decel_counts_per_tick2, steps: int):
    """Emergency braking (§4.1.4, §4.1.5.1): decelerate from ``velocity``
    [counts/tick] to zero at ``decel_counts_per_tick2``, then hold.

    ``position`` and ``velocity`` are float arrays (the exact braking state);
    returns (way-points [counts, int64, shape (steps, 6)], final position,
    final velocity) so a longer stop continues exactly in the next queue load.
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
    """Distance [counts] covered by :func:`braking_profile` from ``velocity`` until stopped."""
    v = np.abs(np.asarray(velocity, float))
    a = np.asarray(decel_counts_per_tick2, float)
    n = np.floor(v / a)  # ticks with non-zero speed after the first decrement
    return n * v - a * n * (n + 1) / 2.0
