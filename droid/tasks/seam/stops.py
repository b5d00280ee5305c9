"""Why a seam-tracking run ends (docs/seamtrack.md; the thesis stops its runs by hand, §6.2.5):
the stop reasons and :class:`TrackingStop`, the verdict the report prints."""
from __future__ import annotations

from dataclasses import dataclass

STOP_END = "end of seam"
STOP_LOST = "seam lost"
STOP_UNREACHABLE = "unreachable"
STOP_RUNAWAY = "runaway"
STOP_FAULT = "fault"  # an arm's Status reports a fault it cannot move with (droid.tasks.seam.cycle.arm_faults)
STOP_STALE = "stale"  # an arm's Status stale past the grace (droid.tasks.seam.station)


@dataclass(frozen=True)
class TrackingStop:
    """Why a tracking run ended, where (tool travel [mm]) and in which cycle.

    Not :class:`droid.brain.runtime.program.Stop` (the SIGTERM/SIGINT flag every program
    polls): this is the tracking core's verdict, a value the report prints.
    """

    reason: str  # STOP_END, STOP_LOST, STOP_UNREACHABLE, STOP_RUNAWAY, STOP_FAULT, STOP_STALE
    detail: str
    travel_mm: float
    cycle: int

    def __str__(self) -> str:
        return f"{self.reason} at {self.travel_mm:.1f} mm ({self.detail})"
