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
4. FINE: step ``-dir`` one count per tick until the switch releases (the
   thesis's last step: the edge is the encoder value there).  (Should the
   joint have settled outside the active side, SEARCH resumes.)
5. PROBE (DROID addition, issue 13): the switch is a cam on the link, the
   encoder counts the motor, and between them the harmonic drive deflects.
   At one count per tick the motor stick-slips (Coulomb friction with
   stiction on the motor side) and the link rings on its drive, so the link
   crosses the edge with up to ~0.02 deg of *dynamic* deflection -- the
   motor leads it in the direction of motion -- and an edge taken there is
   off by that much, differently each homing (docs/reis.md).  At rest the
   link, which has no friction of its own, sits at its static deflection,
   which calibration predicts from the robot file.  So the edge is
   bracketed at rest: the target ramps (one count per tick) to a probe
   position, waits ``home_probe_settle_ticks``, and the switch then says on
   which side of the edge the motor's resting position lies; bisection from
   +-``home_probe_counts`` around the caught edge (an end is probed, and the
   bracket widened, only when the edge lies beyond it) until the bracket is
   ``home_probe_resolution_counts`` wide.  The joint's *edge snapshot* is
   the encoder vector at the last probe with the joint's own count at the
   bracket's middle.

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
    PROBE = 8


_NOT_HOMING = (HomePhase.IDLE, HomePhase.DONE, HomePhase.FAILED)  # the phases with no joint being homed


class Homing:
    """State machine; :meth:`step` moves one joint's target per servo tick."""

    def __init__(self, params: ServoParams):
        self.order = tuple(params.home_order)
        self.dirs = np.asarray(params.home_search_dir, np.int64)
        self.speed = int(params.home_speed_counts_per_tick)
        self.fine = int(params.home_fine_counts_per_tick)
        self.limit = int(params.home_search_limit_counts)
        self.settle_ticks = int(params.home_settle_ticks)
        self.probe_counts = int(params.home_probe_counts)
        self.probe_resolution = int(params.home_probe_resolution_counts)
        self.probe_settle = int(params.home_probe_settle_ticks)
        self.probe_max = int(params.home_probe_max)
        self.probes = 0  # probes of the joint being bracketed
        self._lo = self._hi = 0.0  # the bracket in u = dir * counts: off at rest at lo, on at rest at hi
        self._lo_ok = self._hi_ok = False  # whether each end was seen at rest
        self._goal = 0  # the probe's target, extended counts
        self.phase = HomePhase.IDLE
        self.index = 0
        self.edges = np.zeros((6, 6))  # [counts, float]
        self._previous = np.zeros(6)
        self._travel = 0
        self._settle = 0

    @property
    def joint(self) -> int | None:
        """The joint (0-based) being homed, or None."""
        if self.phase in _NOT_HOMING:
            return None
        return self.order[self.index]

    @property
    def active(self) -> bool:
        return self.phase not in _NOT_HOMING  # joint is not None (read every servo tick)

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
        if self.phase == HomePhase.PROBE:
            return self._probe(position, on, target, j, d)
        # FINE
        if on:
            self._previous = position.astype(float)
            return self._move(target, j, -d * self.fine)
        caught = 0.5 * (float(position[j]) + float(self._previous[j])) * d  # the edge in motion, u
        if self.probe_resolution <= 0:  # probing switched off: the thesis's edge in motion
            self.edges[j] = 0.5 * (position + self._previous)
            return self._next_joint()
        self.phase = HomePhase.PROBE
        self.probes = 0
        self._lo, self._lo_ok = caught - self.probe_counts, False
        self._hi, self._hi_ok = caught + self.probe_counts, False
        self._goal = int(round(0.5 * (self._lo + self._hi))) * d
        self._settle = 0
        return self.phase

    def _next_joint(self) -> HomePhase:
        self.index += 1
        self.phase = HomePhase.DONE if self.index == len(self.order) else HomePhase.START
        return self.phase

    def _probe(self, position: np.ndarray, on: bool, target: np.ndarray, j: int, d: int) -> HomePhase:
        """One tick of step 5: ramp to the probe, rest, read the switch, bisect."""
        if target[j] != self._goal:
            step = max(-self.fine, min(self.fine, self._goal - int(target[j])))
            self._settle = 0
            return self._move(target, j, step)
        self._settle += 1
        if self._settle < self.probe_settle:
            return self.phase
        u = float(position[j]) * d  # where the motor rests
        if on:
            self._hi, self._hi_ok = u, True
            if self._lo >= self._hi:
                self._lo, self._lo_ok = self._hi - self.probe_counts, False
        else:
            self._lo, self._lo_ok = u, True
            if self._hi <= self._lo:
                self._hi, self._hi_ok = self._lo + self.probe_counts, False
        self.probes += 1
        if self._hi - self._lo > self.probe_resolution:
            goal = 0.5 * (self._lo + self._hi)
        elif not self._lo_ok:
            goal = self._lo
        elif not self._hi_ok:
            goal = self._hi
        else:
            goal = None
        if goal is None or self.probes >= self.probe_max:
            self.edges[j] = position.astype(float)
            self.edges[j, j] = 0.5 * (self._lo + self._hi) * d
            return self._next_joint()
        self._goal = int(round(goal)) * d
        self._settle = 0
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
