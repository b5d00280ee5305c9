"""What the servo records about each emergency stop (thesis §4.1.5.1), in its own ticks.

The servo brakes when its command stream stops (the queue and the cache ran
dry: the Brain link was lost, the planner or the servo agent went silent).
:class:`BrakeRecorder` watches the servo core once per 500 Hz tick and, for
every stop, records

* ``last_command_tick`` — the last servo tick at which a command message
  arrived (the servo agent stops sending at most one 60 Hz period after the
  Brain link was declared lost, so this is no later than the detection);
* ``starved_tick`` — the first tick of the braking profile;
* ``cmd_zero_tick`` — the first tick at which the braking profile's velocity
  is zero on every joint;
* ``standstill_tick`` — the first tick at which no joint moves on in its
  direction of travel (at the last command) by more than ``still_counts``
  counts per tick: the arm's velocity has reached zero (the position loop may
  then pull back a few counts of overshoot);
* ``settled_tick`` — the first tick of ``still_ticks`` ticks in a row in
  which no measured encoder moved more than ``still_counts`` counts per tick;
* ``speed_counts_per_tick`` — the largest measured joint speed at the last
  command, and ``travel_counts`` — how far each joint moved from the last
  command to the standstill.

Pure: the shell feeds it ticks and positions and prints the finished records
(one JSON object, on the servo's log).  Wall-clock time never enters it.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

SERVO_TICK_S = 0.002  # 500 Hz


@dataclass(frozen=True)
class BrakeEvent:
    last_command_tick: int
    starved_tick: int
    cmd_zero_tick: int
    standstill_tick: int
    settled_tick: int
    speed_counts_per_tick: int
    travel_counts: tuple[int, ...]

    @property
    def stop_ticks(self) -> int:
        """Servo ticks from the last command to the measured standstill (velocity zero)."""
        return self.standstill_tick - self.last_command_tick

    @property
    def stop_ms(self) -> float:
        """:attr:`stop_ticks` in milliseconds of servo time (2 ms a tick)."""
        return self.stop_ticks * SERVO_TICK_S * 1e3

    def as_dict(self) -> dict:
        d = asdict(self)
        d["travel_counts"] = list(self.travel_counts)
        d.update(stop_ticks=self.stop_ticks, stop_ms=round(self.stop_ms, 1),
                 settle_ms=round((self.settled_tick - self.last_command_tick) * SERVO_TICK_S * 1e3, 1))
        return d


class BrakeRecorder:
    """Turns the servo's per-tick state into :class:`BrakeEvent` records.  Pure."""

    def __init__(self, still_counts: int = 1, still_ticks: int = 5, min_speed_counts_per_tick: int = 2):
        self.still_counts = still_counts
        self.still_ticks = still_ticks
        self.min_speed = min_speed_counts_per_tick  # slower than this at the last command: not a stop worth recording
        self._prev: np.ndarray | None = None
        self._prev_at_cmd: np.ndarray | None = None
        self._last_cmd_tick = 0
        self._pos_at_cmd: np.ndarray | None = None
        self._speed_at_cmd = 0
        self._starved_tick: int | None = None
        self._zero_tick: int | None = None
        self._still_since: int | None = None
        self._dir: np.ndarray | None = None  # sign of each joint's velocity at the last command
        self._stand_tick: int | None = None
        self._done = True  # no stop in progress

    def step(self, tick: int, command_arrived: bool, starved: bool, braking: bool,
             encoder_pos_counts) -> BrakeEvent | None:
        """One servo tick, after the core's step; returns a record when a stop completes."""
        pos = np.asarray(encoder_pos_counts, np.int64)
        same = self._prev is not None and self._prev.shape == pos.shape
        vel = pos - self._prev if same else np.zeros_like(pos)
        speed = np.abs(vel)
        self._prev_at_cmd = self._prev if same else None
        self._prev = pos
        if command_arrived:
            self._last_cmd_tick = tick
            self._pos_at_cmd = pos
            self._speed_at_cmd = int(speed.max()) if speed.size else 0
            self._dir = np.sign(pos - self._prev_at_cmd) if self._prev_at_cmd is not None else None
        if not starved:
            self._starved_tick = self._zero_tick = self._still_since = self._stand_tick = None
            self._done = False
            return None
        if self._done:
            return None
        if self._starved_tick is None:
            self._starved_tick = tick
        if self._zero_tick is None and not braking:
            self._zero_tick = tick
        if self._stand_tick is None and self._dir is not None and np.all(vel * self._dir <= self.still_counts):
            self._stand_tick = tick
        if np.all(speed <= self.still_counts):
            if self._still_since is None:
                self._still_since = tick
        else:
            self._still_since = None
        if self._zero_tick is None or self._still_since is None or tick - self._still_since + 1 < self.still_ticks:
            return None
        self._done = True
        if self._speed_at_cmd < self.min_speed or self._pos_at_cmd is None:
            return None
        stand = self._stand_tick if self._stand_tick is not None else self._still_since
        return BrakeEvent(self._last_cmd_tick, self._starved_tick, self._zero_tick, stand, self._still_since,
                          self._speed_at_cmd, tuple(int(x) for x in pos - self._pos_at_cmd))
