"""Speed and separation monitoring between two arms (issue 41; docs/guard.md).

ISO 10218-2:2025 (which absorbed ISO/TS 15066, eq. 1) states the protective separation
distance between a robot and a person as

    S_p = S_h + S_r + S_s + C + Z_d + Z_r

S_h = v_h (T_r + T_s): the person's travel while the robot reacts and stops; S_r = v_r T_r: the
robot's travel during the reaction time; S_s: the robot's stopping distance; C: the intrusion
distance; Z_d, Z_r: the position uncertainties of the sensing and of the robot.

Between two arms both are robots and both are stopped by the guard's protective stop, so
here the terms are those of the pair's *closing speed* v [mm/s] -- the rate at which the
distance between their closest bodies falls, from both arms' motion (measured joints and the
way-points their planners will send, :mod:`droid.guard.core`):

* S_r = v T_r: the travel during the guard's reaction T_r [s] (its own latency: one heartbeat
  tick to see, one to act, plus the planner's and servo's delay before braking starts);
* S_s = v T_s / 2: the closing while both arms brake to rest in the stopping time T_s [s]
  (constant deceleration; T_s the longer arm's, from its servo's braking);
* S_h: none of its own -- the other arm's motion is already in v (it is a robot that stops);
* C: the clearance the stop must keep [mm] (the *stated limit*: the separation never falls below it);
* Z = Z_a + Z_b: the bodies' uncertainty [mm] (the capsules' fit to the links, the joints'
  measurement).

So ``S_p = v (T_r + T_s / 2) + C + Z``.  The speed override ramps linearly from 1 at ``S_p + band``
down to 0 at S_p, the band being the distance the pair closes in ``slow_s`` at its closing speed,
at most ``slow_mm`` (so two arms that work near each other without closing, a welder beside its
holder, are not slowed); at or below S_p the guard stops both arms (FAULT_COLLISION).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from droid.cli import BadInput

CLEAR, SLOWING, STOPPED = "clear", "slowing", "stopped"
STATES = (CLEAR, SLOWING, STOPPED)


@dataclass(frozen=True)
class SsmParams:
    """The terms of S_p (see the module docstring); times in s, lengths in mm."""

    reaction_s: float = 0.1  # T_r: the Status a tick old, the guard's tick, the planner's next tick, the servo's lag
    stop_time_s: float = 0.3  # T_s: the planner's 15-tick (0.25 s) protective-stop ramp and margin (docs/guard.md)
    clearance_mm: float = 25.0  # C: the stated limit
    uncertainty_mm: float = 10.0  # Z: both arms' bodies together
    slow_mm: float = 200.0  # the override's ramp above S_p, at most [mm]
    slow_s: float = 0.5  # ... the distance closed in this time at the closing speed [s]

    def separation_mm(self, closing_mm_s: float) -> float:
        """S_p [mm] for a closing speed [mm/s] (a separating pair, v < 0, counts as 0)."""
        v = max(0.0, float(closing_mm_s))
        return v * (self.reaction_s + 0.5 * self.stop_time_s) + self.clearance_mm + self.uncertainty_mm

    def override(self, distance_mm: float, closing_mm_s: float) -> float:
        """The speed override in [0, 1]: 1 beyond S_p + band, 0 at S_p, linear between (band: the
        distance closed in ``slow_s`` at the closing speed, at most ``slow_mm``)."""
        sp = self.separation_mm(closing_mm_s)
        band = min(self.slow_mm, max(0.0, float(closing_mm_s)) * self.slow_s)
        if band <= 0.0:
            return 1.0 if distance_mm > sp else 0.0
        return min(1.0, max(0.0, (float(distance_mm) - sp) / band))

    def state(self, distance_mm: float, closing_mm_s: float) -> str:
        """clear / slowing / stopped for a distance [mm] and closing speed [mm/s]."""
        o = self.override(distance_mm, closing_mm_s)
        return CLEAR if o >= 1.0 else (STOPPED if o <= 0.0 else SLOWING)


_KEYS = {"reaction_s": (0.0, 5.0), "stop_time_s": (0.0, 10.0), "clearance_mm": (0.0, 1000.0),
         "uncertainty_mm": (0.0, 1000.0), "slow_mm": (0.0, 5000.0), "slow_s": (0.0, 10.0)}


def ssm_params(table, where: str) -> SsmParams:
    """``[guard.ssm]`` (any of :class:`SsmParams`' fields) -> SsmParams; a bad key or value is one line."""
    if table is None:
        return SsmParams()
    if not isinstance(table, dict):
        raise BadInput(f"{where}: [guard] ssm: must be a table")
    unknown = sorted(set(table) - set(_KEYS))
    if unknown:
        raise BadInput(f"{where}: [guard] ssm: unknown key(s): {', '.join(unknown)} (known: {', '.join(_KEYS)})")
    vals = {}
    for k, v in table.items():
        lo, hi = _KEYS[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            raise BadInput(f"{where}: [guard] ssm: {k}: must be a number in [{lo:g}, {hi:g}], got {v!r}")
        vals[k] = float(v)
    return SsmParams(**vals)
