"""Moves that would collide are refused before anything moves (issue 41 item 3; docs/guard.md).

:func:`check_move` samples a commanded joint move of one arm -- a straight line in joint
space, as the Reis planner interpolates it (linear in encoder counts, and counts are linear in
the joints) -- against the other arms where they stand or, for an arm on a move of its own,
along that move (time-aligned: both interpolated over their own durations from now), and
returns the one-line refusal

    would collide: arm1 link 4 with gmf1 link 3 at 42 % of the move (clearance 12 mm < 25 mm)

for the sample with the least clearance when it is below the limit (the ``[guard] ssm``
clearance C plus the uncertainty Z), else None.  The percentage is the share of the move's
time.  Joint vectors in deg, lengths in mm.

An other arm's move that lasts longer than this one is followed to its end, this arm standing at
its goal meanwhile (session 26: before, the samples stopped with this move, so a reach that ended
in the other arm's path, before that arm's sweep passed there, was found clear); such a sample
is named ``after the move (+0.8 s, at its goal)``.
"""
from __future__ import annotations

import numpy as np

from droid.guard.cell import GuardScene

#: samples of a move: one every this many degrees of its largest joint change, within the bounds
SAMPLE_DEG = 1.0
MIN_SAMPLES, MAX_SAMPLES = 21, 721


def _samples(span_deg: float) -> int:
    return int(min(MAX_SAMPLES, max(MIN_SAMPLES, np.ceil(span_deg / SAMPLE_DEG) + 1)))


def check_move(scene: GuardScene, arm: str, q_from_deg, q_to_deg, seconds: float, others_deg: dict,
               others_moves: dict | None = None, limit_mm: float = 35.0) -> str | None:
    """The refusal line for ``arm``'s joint move ``q_from_deg`` -> ``q_to_deg`` over ``seconds``, or None.

    ``others_deg``: every other arm's joints now [deg]; ``others_moves``: arm -> (goal [deg],
    seconds left) for an arm on a move of its own (it is interpolated toward its goal and then
    stands there)."""
    q0, q1 = np.asarray(q_from_deg, float), np.asarray(q_to_deg, float)
    seconds = float(seconds)
    n = _samples(float(np.max(np.abs(q1 - q0))) if q1.size else 0.0)
    horizon = seconds  # the last of the moves' ends [s]: this one's, or an other arm's later one
    for name, (goal, left) in (others_moves or {}).items():
        if left > 0:
            n = max(n, _samples(float(np.max(np.abs(np.asarray(goal, float) - np.asarray(others_deg[name], float))))))
            horizon = max(horizon, float(left))
    if horizon > seconds:  # as many samples over this move as without the longer one, within the bound
        n = int(min(MAX_SAMPLES, np.ceil(n * horizon / seconds)))
    t = np.linspace(0.0, horizon, n)
    s = np.clip(t / seconds, 0.0, 1.0) if seconds > 0 else np.ones(n)
    q = {arm: q0 + s[:, None] * (q1 - q0)}
    for name, qn in others_deg.items():
        qn = np.asarray(qn, float)
        move = (others_moves or {}).get(name)
        if move is None or move[1] <= 0:
            q[name] = np.broadcast_to(qn, (n, 6))
        else:
            f = np.clip(t / float(move[1]), 0.0, 1.0)
            q[name] = qn + f[:, None] * (np.asarray(move[0], float) - qn)
    d = scene.distances(q)  # (n, pairs)
    own = np.array([a.owner == arm or b.owner == arm for a, b in scene.pairs])
    if not own.any():
        return None
    d = np.where(own[None, :], d, np.inf)  # only pairs the move can change
    i, k = np.unravel_index(int(np.argmin(d)), d.shape)
    least = float(d[i, k])
    if least >= limit_mm:
        return None
    a, b = scene.pairs[k]
    if b.owner == arm:
        a, b = b, a
    when = (f"at {100.0 * s[i]:.0f} % of the move" if t[i] <= seconds
            else f"after the move (+{t[i] - seconds:.1f} s, at its goal)")
    return f"would collide: {a.label()} with {b.label()} {when} (clearance {least:.0f} mm < {limit_mm:.0f} mm)"
