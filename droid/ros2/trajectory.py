"""A trajectory_msgs/JointTrajectory as droid-move's joint moves (issue 42; docs/ros2.md).

The topic interface of ros2_control's joint_trajectory_controller: ``joint_names`` and
``points``, each point ``positions`` [rad] at ``time_from_start``.  :func:`plan` checks a whole
trajectory *before* anything is written -- the joint names, every number finite, the times
strictly increasing, and every segment with droid-move's own checks
(:meth:`droid.tasks.arm.BrainArm.ticks_for` and :meth:`~droid.tasks.arm.BrainArm.check_joint_target`:
encoder and joint limits, the joint speed limits from the previous point, the first from where
the arm stands) -- and returns one :class:`Leg` (a joint move) per segment, or raises
:class:`~droid.cli.BadInput` with the reason: a refused trajectory moves nothing.

What is not taken from the message: ``velocities``, ``accelerations`` and ``effort`` of the
points (DROID's planner makes its own profile of each move in its time), and ``header.stamp``
(a trajectory starts when it is received).  Pure: no ROS import (plain lists in).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from droid.cli import BadInput

JOINT_NAMES = tuple(f"joint_{i}" for i in range(1, 7))  # as droid-kin urdf names them (ROS-Industrial)
MAX_POINTS = 10000  # more points than this is refused (each becomes a move of at least one tick)


@dataclass(frozen=True)
class Leg:
    """One segment of a trajectory as a joint move: its target [encoder counts] and time [s]."""

    counts: np.ndarray
    seconds: float
    t_end_s: float  # the point's time_from_start [s]


def duration_s(sec: int, nanosec: int) -> float:
    """builtin_interfaces/Duration as seconds."""
    return float(sec) + float(nanosec) * 1e-9


def _order(names: list[str]) -> list[int]:
    """For each of joint_1..joint_6 its index in ``names``; BadInput naming what is wrong."""
    names = [str(n) for n in names]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise BadInput(f"wrong joint names: {', '.join(dup)} given twice")
    extra = [n for n in names if n not in JOINT_NAMES]
    missing = [n for n in JOINT_NAMES if n not in names]
    if extra or missing:
        parts = ([f"unknown {', '.join(extra)}"] if extra else []) + ([f"missing {', '.join(missing)}"] if missing else [])
        raise BadInput(f"wrong joint names ({'; '.join(parts)}): the arm's joints are {', '.join(JOINT_NAMES)}")
    return [names.index(n) for n in JOINT_NAMES]


def plan(arm, joint_names: list[str], points: list[tuple[list[float], float]], q_now_deg) -> list[Leg]:
    """The legs of a trajectory for ``arm`` (a :class:`~droid.tasks.arm.BrainArm`) from ``q_now_deg``
    (its joints now [deg]).  ``points``: ``[(positions [rad] in ``joint_names`` order, time_from_start [s])]``.
    BadInput (nothing is written) for an empty, malformed, out-of-limit or too fast trajectory."""
    if not points:
        raise BadInput("empty trajectory: no points")
    if len(points) > MAX_POINTS:
        raise BadInput(f"too many points: {len(points)} (at most {MAX_POINTS})")
    order = _order(list(joint_names))
    legs: list[Leg] = []
    q_prev = np.asarray(q_now_deg, float)
    t_prev = 0.0
    for k, (positions, t) in enumerate(points, start=1):
        pos = list(positions)
        if len(pos) != len(order):
            raise BadInput(f"point {k}: {len(pos)} positions for {len(order)} joint names")
        bad = [JOINT_NAMES[i] for i, j in enumerate(order) if not math.isfinite(float(pos[j]))]
        if bad:
            raise BadInput(f"point {k}: position of {', '.join(bad)} is not a finite number "
                           f"({', '.join(repr(float(pos[order[JOINT_NAMES.index(b)]])) for b in bad)})")
        t = float(t)
        if not math.isfinite(t) or t <= t_prev:
            raise BadInput(f"point {k}: time_from_start {t:g} s must be after "
                           f"{'the start (0 s)' if k == 1 else f'point {k - 1} ({t_prev:g} s)'}")
        seconds = t - t_prev
        q_deg = np.degrees(np.asarray([float(pos[j]) for j in order], float))
        try:
            arm.ticks_for(seconds)
            counts = np.rint(arm.model.gearing.joints_to_counts(q_deg))
            counts = arm.check_joint_target(counts, seconds, q_prev)
        except BadInput as exc:
            raise BadInput(f"point {k} ({t:g} s): {exc}") from None
        legs.append(Leg(counts=counts, seconds=seconds, t_end_s=t))
        q_prev = arm.model.gearing.counts_to_joints(np.asarray(counts, float))
        t_prev = t
    return legs
