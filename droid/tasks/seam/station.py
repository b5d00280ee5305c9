"""The seam tracker as one station: a tick's Status records in, the tick's Commands out
(issue 25 item 3; thesis §5.5, Figure 5.9; docs/design.md §11 "A task is a station too").

``droid-seamtrack`` (the real-time shell, droid/tasks/seamtrack.py) and the lockstep
trial (droid/experiments/trial.py) both call :meth:`SeamtrackStation.on_tick` once a
heartbeat tick with what the Brain's databases hold for that tick -- each arm's Status
(:class:`ArmStatus`) and, through a callable read only when a cycle runs, the lead
sensor's reading -- and write the commands it returns.  Everything between the records
and the commands is here, so the two runners cannot drift apart:

* the pose histories (:meth:`TrackingCycle.remember`), fed only while neither arm is
  stale;
* the cycle's due tick (30 Hz) and the log's (10 Hz), counted in heartbeat ticks;
* the fault rule (:meth:`TrackingCycle.check_faults`) every tick, before any command;
* **the stale rule**, counted in heartbeat ticks (it was counted in wall seconds inside
  droid-seamtrack's loop): while an arm's Status is stale no command is written (the
  Reis finishes its last step and waits); stale for more than ``stale_grace_ticks``
  ends the run (``stale``, its detail ``"<arm> went stale"``);
* the core's step and the commands it returns: the Reis's cartesian command every
  cycle, the holder's on the first (``gen_hold_robot_wcp``).

What a shell still does is I/O and time: read the records, write the commands for
``cycle_ticks`` ticks, log rows, and (real time only) notice a silent heartbeat.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from droid.tasks.seam.core import CycleOutput
from droid.tasks.seam.stops import STOP_STALE, TrackingStop
from droid.tasks.seam.cycle import TrackingCycle
from droid.tasks.seam.delay import INVALID_READING, Reading

#: An arm's Status stale for this many heartbeat ticks ends the run (2 s at 60 Hz; the same
#: grace droid-move and droid-home give a stale Status, droid.tasks.arm.STALE_GRACE_S).
STALE_GRACE_S = 2.0


def stale_grace_ticks(heartbeat_hz: float) -> int:
    """:data:`STALE_GRACE_S` in whole heartbeat ticks (at least one)."""
    return max(1, round(STALE_GRACE_S * float(heartbeat_hz)))


@dataclass(frozen=True)
class ArmStatus:
    """One arm's Status record as the station reads it at a tick.

    ``fault`` is the Status's fault bits, or None for a holder that has none (a fixed
    fixture); ``joints_deg`` is called only on a cycle tick (the Reis's joint angles [deg]
    for the core's wrist-flip guard)."""

    name: str
    tick: int  # the Status record's own tick [heartbeat ticks]
    pose: np.ndarray  # global wrist-centre pose, 4x4 [mm]
    fault: int | None = 0
    stale: bool = False
    joints_deg: Callable[[], np.ndarray] | None = None


@dataclass
class StationOutput:
    """What one tick gives the shell to write."""

    tool_cmd: np.ndarray | None = None  # cartesian command of the tool robot, for cycle_ticks ticks
    hold_cmd: np.ndarray | None = None  # the holder's (first cycle only)
    stop: TrackingStop | None = None  # why the run ends (the core's stop, a fault, a stale arm)
    log: bool = False  # a 10 Hz log row is due at this tick


class SeamtrackStation:
    """The tracker's cycle between the Brain's records and its commands (module docstring).

    ``first_cycle_tick`` / ``first_log_tick``: no cycle (log row) before these ticks
    [heartbeat ticks] -- the lockstep trial lets the pose history fill for one cycle first
    and logs from its second tick; droid-seamtrack starts at once (None)."""

    def __init__(self, cyc: TrackingCycle, heartbeat_hz: float, *, first_cycle_tick: int | None = None,
                 first_log_tick: int | None = None) -> None:
        self.cyc = cyc
        self.stale_grace_ticks = stale_grace_ticks(heartbeat_hz)
        self.first_cycle_tick = first_cycle_tick
        self.first_log_tick = first_log_tick
        self.stale_since: int | None = None
        self.out: CycleOutput | None = None  # the newest cycle's output
        self.lead: Reading = INVALID_READING  # the reading the newest cycle used
        self.done: TrackingStop | None = None

    @property
    def cycle_ticks(self) -> int:
        return self.cyc.cycle_ticks

    def on_tick(self, tick: int, tool: ArmStatus, hold: ArmStatus,
                lead: Callable[[], tuple[Reading, int]]) -> StationOutput:
        """One heartbeat tick: remember both poses, and when a cycle is due, run it.

        ``lead()`` returns the lead sensor's reading and the tick of the Status it came in;
        it is called only when a cycle steps the core."""
        if self.done is not None:
            return StationOutput(stop=self.done)
        if not tool.stale and not hold.stale:
            self.cyc.remember(tool.tick, tool.pose, hold.tick, hold.pose)
        # the fault rule every tick, not only on cycles: a protective stop's bit may show for
        # fewer ticks than a cycle has (the planner re-anchors at once), and the stop comes sooner
        fault = self.cyc.check_faults([(a.name, a.fault) for a in (tool, hold) if a.fault is not None])
        if fault is not None:
            self.done = fault
            return StationOutput(stop=fault)
        res = StationOutput()
        if (self.first_cycle_tick is None or tick >= self.first_cycle_tick) and self.cyc.due(tick):
            res = self._cycle(tick, tool, hold, lead)
            if res.stop is not None:
                self.done = res.stop
                return res
        res.log = (self.first_log_tick is None or tick >= self.first_log_tick) and self.cyc.log_due(tick)
        return res

    def _cycle(self, tick: int, tool: ArmStatus, hold: ArmStatus, lead) -> StationOutput:
        stale = [a for a in (tool, hold) if a.stale]
        if stale:  # no command this cycle: the tool robot finishes its last step and waits
            if self.stale_since is None:
                self.stale_since = tick
            if tick - self.stale_since > self.stale_grace_ticks:
                names = ", ".join(a.name for a in stale)
                return StationOutput(stop=self.cyc.core.halt(STOP_STALE, f"{names} went stale"))
            return StationOutput()
        self.stale_since = None
        reading, reading_tick = lead()
        self.lead = reading
        joints = tool.joints_deg() if tool.joints_deg is not None else None
        out = self.cyc.step(hold.pose, tool.pose, tool.tick, reading, reading_tick, joints)
        self.out = out
        if out.stop is not None:
            return StationOutput(stop=out.stop)
        hold_cmd = out.hold_cmd if out.cycle == 0 else None  # gen_hold_robot_wcp: the holder keeps its pose
        return StationOutput(tool_cmd=out.tool_cmd, hold_cmd=hold_cmd)
