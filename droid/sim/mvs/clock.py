"""The sensors' frame clock: events at a fixed rate against world time (60 Hz video, thesis §2.5)."""

from __future__ import annotations

class FrameClock:
    """Fires at ``rate_hz`` against accumulated world time (integer ns, no drift).

    ``advance(dt_s)`` returns True when at least one event fell due in the
    step; events beyond one in a step (a world slower than the rate, or a
    catch-up) are counted in ``skipped``.
    """

    def __init__(self, rate_hz: float) -> None:
        if not rate_hz > 0:
            raise ValueError("rate must be > 0 Hz")
        self.rate_hz = float(rate_hz)
        self.t_ns = 0
        self.fired = 0
        self.skipped = 0
        self._k = 0  # events due so far (the first at t = 0)

    def advance(self, dt_s: float) -> bool:
        self.t_ns += int(round(dt_s * 1e9))
        due = int(self.t_ns * self.rate_hz // 1e9) + 1
        n = due - self._k
        if n <= 0:
            return False
        self._k = due
        self.fired += 1
        self.skipped += n - 1
        return True
