"""The planners' side of the collision guard: its stale rule and its override (issue 41 items 2-3).

droid-guard (and its lockstep station) writes two fields into every guarded arm's Brain Command
on each heartbeat tick it runs a pass (:data:`droid.brain.db.layouts.ARM_COMMAND`, version 2):
``guard_tick``, the tick of the pass, and ``guard_override``, the arm's speed override in 0..1.
The agent copies them into the controller's Command with the rest of the record
(``ARM6R.command_map``), so a planner on another host sees them on its relayed tick.

Where the cell declares a guard (a ``[guard]`` table), a planner keeps a :class:`GuardGate`:

* **a dead guard stops the cell** -- the guard's record is *stale* when its ``guard_tick`` is 0
  (the guard has not run yet) or more than ``[guard] stale_ticks`` ticks behind the relayed
  tick.  While it is stale the gate sets :data:`~droid.brain.db.layouts.FAULT_GUARD` in the arm's
  own Status, and the planner treats it as FAULT_COLLISION: a running move is ended along its
  path (the protective stop's ramp) and a new NORMAL command is refused (a stop command is
  still taken).  The bit clears at the first fresh record;
* **the override** -- the planner advances its way-point by ``speed`` of a tick's step, where
  ``speed`` follows the guard's override at most :data:`RAMP` a tick either way (the protective
  stop's deceleration: a sudden fall held at once overran the Reis servo's following error).

The GMF1's serial program (the KAREL server interpolates its moves itself) keeps the stale rule
only (:func:`stale`): droid.subunits.gmf1.serial_core.
"""
from __future__ import annotations

import math

from droid.brain.db.layouts import FAULT_GUARD
from droid.cli import BadInput

#: ``[guard] stale_ticks`` when the cell gives none: 100 ms at 60 Hz (the pass writes every tick;
#: the record a planner reads is normally one or two ticks old)
DEFAULT_STALE_TICKS = 6
STALE_TICKS_RANGE = (2, 600)
#: the applied speed follows the override by at most this a tick (1/15: the protective stop's
#: 15-tick ramp, droid.arm.planner.COLLISION_BRAKE_TICKS)
RAMP = 1.0 / 15.0


def guard_runs(cell) -> bool:
    """Does the cell run the live guard -- droid-guard started by droid-cell up, and the planners'
    stale rule and override?  Where it declares ``[guard]`` and its ``run`` is true (the default).
    ``run = false`` keeps the guard's bodies for droid-move's refusal, droid-cell up's home check
    and droid-guard check, with no live guard (the shipped cells: docs/guard.md "The live guard
    on the shipped cells").  A ``run`` that is not true or false is one line (BadInput)."""
    table = cell.raw.get("guard")
    if not isinstance(table, dict):
        return table is not None
    run = table.get("run", True)
    if not isinstance(run, bool):
        raise BadInput(f"{cell.path}: [guard] run: must be true or false, got {run!r}")
    return run


def guard_stale_ticks(cell) -> int | None:
    """The cell's ``[guard] stale_ticks`` (default :data:`DEFAULT_STALE_TICKS`); None when the
    cell runs no live guard (:func:`guard_runs`: its planners keep no gate).  A bad value is one
    line (BadInput)."""
    table = cell.raw.get("guard")
    if table is None or not guard_runs(cell):
        return None
    v = table.get("stale_ticks", DEFAULT_STALE_TICKS) if isinstance(table, dict) else DEFAULT_STALE_TICKS
    lo, hi = STALE_TICKS_RANGE
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise BadInput(f"{cell.path}: [guard] stale_ticks: must be an integer in [{lo}, {hi}] "
                       f"(heartbeat ticks), got {v!r}")
    return v


def stale(cmd, tick: int, stale_ticks: int) -> bool:
    """Is the guard's record in a controller Command (its ``guard_tick``) stale at relayed ``tick``?"""
    g = int(cmd["guard_tick"])
    return g == 0 or int(tick) - g > stale_ticks


def override_of(cmd) -> float:
    """The guard's override in a Command record, clipped to 0..1 (not a number: 0)."""
    o = float(cmd["guard_override"])
    return min(1.0, max(0.0, o)) if math.isfinite(o) else 0.0


def set_fault_bit(ctrl_status, bit: int, on: bool) -> None:
    """One fault bit in an arm's own Status, its other bits kept (a locked read-modify-write)."""
    with ctrl_status.locked() as st:
        st["fault"] = (int(st["fault"]) & ~bit) | (bit if on else 0)
        ctrl_status.mark_written()


class GuardGate:
    """A planner's view of the guard (see the module docstring): ``stale_ticks`` from the cell."""

    def __init__(self, stale_ticks: int) -> None:
        self.stale_ticks = int(stale_ticks)
        self.is_stale: bool | None = None  # as last written into the Status (None: not yet)
        self.speed = 1.0  # the applied speed factor
        self.stale_events = 0  # times the record went stale

    def apply(self, cmd, status, tick: int, ctrl_status) -> float:
        """One relayed tick: FAULT_GUARD in ``ctrl_status`` (and in ``status``, this tick's copy the
        planner steps on) while the guard's record is stale; returns the speed factor to apply."""
        now = stale(cmd, tick, self.stale_ticks)
        if now != self.is_stale:
            set_fault_bit(ctrl_status, FAULT_GUARD, now)
            self.stale_events += int(bool(now))
            self.is_stale = now
        status["fault"] = (int(status["fault"]) & ~FAULT_GUARD) | (FAULT_GUARD if now else 0)
        target = 0.0 if now else override_of(cmd)
        self.speed = min(self.speed + RAMP, target) if target > self.speed else max(self.speed - RAMP, target)
        return self.speed
