"""When a program that feeds an arm controller cycles: :class:`TickPacer` (thesis §4.1.6; issue 16).

droid-servo-agent (the Reis) and droid-egm (the ABB on EGM) both send their controller the
planner's way-point once per relayed heartbeat tick, after the planner wrote it, and keep sending
on their own clock when the ticks stop, so the controller brakes through its profile instead of
running on.  The pacer is what they share (the neutral arm, :mod:`droid.arm`).
"""
from __future__ import annotations

import time


class TickPacer:
    """When droid-servo-agent cycles: on each relayed heartbeat tick, once the planner has
    written that tick's way-point (it cycles on the same tick; waited for up to
    ``PLANNER_WAIT_NS``), and on its own clock when the ticks stop -- first 1.5 periods
    after the last cycle, then every period -- so that the servo brakes through the
    profile when the Brain or its link goes silent (thesis §4.1.6's 60 Hz; issue 16)."""

    PLANNER_WAIT_NS = 6_000_000  # [ns] (a third of a period)
    POLL_NS = 250_000  # [ns]

    def __init__(self, period_ns: int) -> None:
        self.period_ns = int(period_ns)
        self.last_ns: int | None = time.monotonic_ns()  # until the first tick: every period
        self.last_ticked = False
        self.cycles = 0
        self.untimed = 0  # cycles on the own clock (no tick came)
        self.late_max_ns = 0  # [ns] worst gap beyond one period between cycles

    def deadline_ns(self) -> int | None:
        if self.last_ns is None:
            return None
        return self.last_ns + (self.period_ns * 3 // 2 if self.last_ticked else self.period_ns)

    def wait_s(self, now_ns: int) -> float:
        """How long to wait for a tick [s]."""
        d = self.deadline_ns()
        return 0.5 if d is None else min(0.5, max(0.0, (d - now_ns) / 1e9))

    def due(self, now_ns: int) -> bool:
        """No tick came: is an own-clock cycle due?"""
        d = self.deadline_ns()
        return d is not None and now_ns >= d

    def late_ns(self, now_ns: int) -> int:
        """How far this cycle runs beyond one period after the last [ns]."""
        return 0 if self.last_ns is None else max(0, now_ns - self.last_ns - self.period_ns)

    def cycled(self, now_ns: int, ticked: bool) -> None:
        self.late_max_ns = max(self.late_max_ns, self.late_ns(now_ns))
        self.last_ns, self.last_ticked = now_ns, ticked
        self.cycles += 1
        self.untimed += not ticked

    def await_planner(self, ctrl_command, tick: int) -> None:
        """Wait (polling) until the planner's way-point of ``tick`` is written."""
        end = time.monotonic_ns() + self.PLANNER_WAIT_NS
        while int(ctrl_command.read()["planner_tick"]) < tick and time.monotonic_ns() < end:
            time.sleep(self.POLL_NS / 1e9)
