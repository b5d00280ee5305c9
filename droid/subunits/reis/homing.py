"""The homing state machine (thesis §4.1.5.3, figure 4.10).

One joint at a time, in ``params.home_order``.  For each joint, with ``dir``
the count direction that activates its switch (the switch is a cam: active on
one side of its position):

1. switch active at the start -> BACKOFF: the joint is past the switch; move
   ``-dir`` at ``home_speed_counts_per_tick`` ("moderate speed", 20 counts per
   tick) until the switch releases;
2. SEARCH: move ``+dir`` at moderate speed until the switch is active;
3. SETTLE (DROID addition): stop the target where it is -- a following error
   ahead of the joint, inside the active side -- and wait
   ``home_settle_ticks`` so the joint comes to rest (the thesis goes straight
   to step 4; a joint still bouncing crosses the edge at speed and the edge
   reads several counts off);
4. FINE: step ``-dir`` one count per tick until the switch releases; the
   joint's *edge snapshot* is the encoder vector there -- the mean of this
   tick's and the previous tick's readings, since the edge was crossed
   somewhere between the two samples.  (Should the
   joint have settled outside the active side, SEARCH resumes.)

The snapshot of joint i is taken with q_i exactly at its known switch
position, so with q = M^-1 (m - z) the six snapshots give six equations
``(M^-1)_i . (E_i - z) = q_sw_i`` for the zero vector z (see
:func:`zero_from_edges`).  Without coupling this reduces to the thesis's
"encoder value minus the known switch position in counts".
"""
from __future__ import annotations

from enum import IntEnum

import numpy as np

from droid.subunits.reis.servo_params import ServoParams


class HomePhase(IntEnum):
    IDLE = 0
    START = 1
    BACKOFF = 2
    SEARCH = 3
    SETTLE = 4
    FINE = 5
    DONE = 6
    FAILED = 7


class Homing:
    """State machine; :meth:`step` moves one joint's target per servo tick."""

    def __init__(self, params: ServoParams):
        self.order = tuple(params.home_order)
        self.dirs = np.asarray(params.home_search_dir, np.int64)
        self.speed = int(params.home_speed_counts_per_tick)
        self.fine = int(params.home_fine_counts_per_tick)
        self.limit = int(params.home_search_limit_counts)
        self.settle_ticks = int(params.home_settle_ticks)
        self.phase = HomePhase.IDLE
        self.index = 0
        self.edges = np.zeros((6, 6))  # [counts, float]
        self._previous = np.zeros(6)
        self._travel = 0
        self._settle = 0

    @property
    def joint(self) -> int | None:
        """The joint (0-based) being homed, or None."""
        if self.phase in (HomePhase.IDLE, HomePhase.DONE, HomePhase.FAILED):
            return None
        return self.order[self.index]

    @property
    def active(self) -> bool:
        return self.joint is not None

    def start(self) -> None:
        self.phase = HomePhase.START
        self.index = 0
        self.edges[:] = 0.0
        self._travel = 0

    def abort(self) -> None:
        self.phase = HomePhase.IDLE

    def step(self, position: np.ndarray, switches, target: np.ndarray) -> HomePhase:
        """Advance one tick: may change ``target`` (int64, in place) for the joint
        being homed; returns the phase (DONE once all six edges are recorded)."""
        j = self.order[self.index]
        d = int(self.dirs[j])
        on = bool(switches[j])
        if self.phase == HomePhase.START:
            self.phase = HomePhase.BACKOFF if on else HomePhase.SEARCH
            self._travel = 0
        if self.phase == HomePhase.BACKOFF:
            if on:
                return self._move(target, j, -d * self.speed)
            self.phase = HomePhase.SEARCH
            self._travel = 0
        if self.phase == HomePhase.SEARCH:
            if not on:
                return self._move(target, j, d * self.speed)
            self.phase = HomePhase.SETTLE
            self._settle = 0
            self._travel = 0
        if self.phase == HomePhase.SETTLE:
            self._settle += 1
            if self._settle < self.settle_ticks:
                return self.phase
            self.phase = HomePhase.FINE if on else HomePhase.SEARCH
            self._previous = position.astype(float)
            return self.phase
        # FINE
        if on:
            self._previous = position.astype(float)
            return self._move(target, j, -d * self.fine)
        self.edges[j] = 0.5 * (position + self._previous)
        self.index += 1
        if self.index == len(self.order):
            self.phase = HomePhase.DONE
        else:
            self.phase = HomePhase.START
        return self.phase

    def _move(self, target: np.ndarray, j: int, counts: int) -> HomePhase:
        self._travel += abs(counts)
        if self._travel > self.limit:
            self.phase = HomePhase.FAILED
            return self.phase
        target[j] += counts
        return self.phase


def zero_from_edges(edges: np.ndarray, switch_deg, joint_to_counts) -> np.ndarray:
    """Encoder zero z [extended counts] from the six edge snapshots.

    Solves (M^-1)_i . (E_i - z) = q_sw_i for all i:
    with b_i = (M^-1)_i . E_i - q_sw_i, (M^-1) z = b, so z = M b.
    """
    m = np.asarray(joint_to_counts, float)
    minv = np.linalg.inv(m)
    b = np.einsum("ij,ij->i", minv, np.asarray(edges, float)) - np.asarray(switch_deg, float)
    return np.rint(m @ b).astype(np.int64)
