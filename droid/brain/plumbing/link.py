"""The Brain <-> agent link state machines (thesis §3.2, figure 3.3; zguide Paranoid Pirate).

On each heartbeat tick the Brain-side remote sends the subunit's Command record
to the agent; the agent copies it into the motion controller's Command record
and replies with its Status record; the remote writes the reply into the
Brain's Status record.  "This send and reply method guarantees that a
connection is established throughout message passing since the reply acts as
an acknowledgment."

Both sides count silence in ticks: ``stale_ticks`` (3) ticks without a reply
mark the subunit stale in the Brain's Status record (remote side), and ticks
without a command mark the Brain link dead on the subunit (agent side), which
makes the motion controller brake (issue: safety).
"""
from __future__ import annotations

from dataclasses import dataclass

from droid.brain.plumbing.wire import LIVENESS_TICKS, MAX_BACKOFF_TICKS


@dataclass
class RemoteAction:
    send: bool = True  # send this tick's command
    reconnect: bool = False  # drop the socket and locate the agent again
    became_stale: bool = False


class RemoteLinkCore:
    """Brain side: liveness of one agent, counted in heartbeat ticks.  Pure."""

    def __init__(self, stale_ticks: int = LIVENESS_TICKS, max_backoff_ticks: int = MAX_BACKOFF_TICKS) -> None:
        self.stale_ticks = stale_ticks
        self.max_backoff_ticks = max_backoff_ticks
        self.pending: int | None = None  # tick of the command awaiting a reply
        self.missed = 0  # consecutive ticks without a reply
        self.stale = True  # until the first reply
        self.replies = 0
        self.late_replies = 0
        self.reconnects = 0
        self._backoff = stale_ticks
        self._since_reconnect = 0

    def on_tick(self, tick: int) -> RemoteAction:
        act = RemoteAction()
        if self.pending is not None:
            self.missed += 1
        self.pending = tick
        self._since_reconnect += 1
        if self.missed >= self.stale_ticks:
            if not self.stale:
                self.stale = True
                act.became_stale = True
            # reconnect with exponential back-off (in ticks)
            if self._since_reconnect >= self._backoff:
                act.reconnect = True
                self.reconnects += 1
                self._since_reconnect = 0
                self._backoff = min(self._backoff * 2, self.max_backoff_ticks)
        return act

    def on_reply(self, tick: int) -> bool:
        """A reply for ``tick`` arrived; True if it answers the pending command."""
        if self.pending is None or tick != self.pending:
            self.late_replies += 1
            return False
        self.pending = None
        self.missed = 0
        self.stale = False
        self.replies += 1
        self._backoff = self.stale_ticks
        return True


class AgentLinkCore:
    """Subunit side: is the Brain still sending?  Pure; time in ns is passed in."""

    def __init__(self, period_ns: int, stale_ticks: int = LIVENESS_TICKS) -> None:
        self.period_ns = period_ns
        self.stale_ticks = stale_ticks
        self.last_cmd_ns: int | None = None
        self.last_tick = 0
        self.commands = 0

    def on_command(self, tick: int, now_ns: int) -> None:
        self.last_cmd_ns = now_ns
        self.last_tick = max(self.last_tick, tick)
        self.commands += 1

    def alive(self, now_ns: int) -> bool:
        """False once ``stale_ticks`` periods passed without a command (or none yet)."""
        if self.last_cmd_ns is None:
            return False
        return now_ns - self.last_cmd_ns < self.stale_ticks * self.period_ns


class HeartbeatWatch:
    """Brain side: has the heartbeat itself gone silent?  Pure; time in ns is passed in.

    A remote is driven by the heartbeat's ticks (thesis §3.2), so when the
    heartbeat dies nothing would refresh -- or mark stale -- its subunit's
    Status: it would freeze with its last values and ``stale = 0``.  The remote
    polls with a timeout of one period and asks :meth:`became_silent`: after
    ``stale_ticks`` periods without a tick it reports the silence once (the
    remote then sets ``stale`` and FAULT_HEARTBEAT); the next tick clears it.
    """

    def __init__(self, period_ns: int, stale_ticks: int = LIVENESS_TICKS) -> None:
        if period_ns <= 0 or stale_ticks < 1:
            raise ValueError("need period_ns > 0 and stale_ticks >= 1")
        self.limit_ns = int(period_ns) * stale_ticks
        self.last_ns: int | None = None
        self.silent = False
        self.silences = 0
        self.poll_ms = max(1, int(round(period_ns / 1e6)))  # the remote's poll timeout: one period

    @classmethod
    def for_rate(cls, heartbeat_hz: float, stale_ticks: int) -> "HeartbeatWatch":
        return cls(int(round(1e9 / heartbeat_hz)), stale_ticks)

    def on_tick(self, now_ns: int) -> bool:
        """A tick arrived at ``now_ns``; True if this ends a silence."""
        self.last_ns = now_ns
        ended, self.silent = self.silent, False
        return ended

    def became_silent(self, now_ns: int) -> bool:
        """True once when no tick came for ``stale_ticks`` periods (counted from the
        first call when no tick was ever seen)."""
        if self.last_ns is None:
            self.last_ns = now_ns
        if not self.silent and now_ns - self.last_ns > self.limit_ns:
            self.silent = True
            self.silences += 1
            return True
        return False
