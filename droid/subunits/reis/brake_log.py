"""What the servo records about each halt of the arm (thesis §4.1.5.1), in its own ticks.

The arm halts at the end of every move, and also when its command stream
stops: the queue and the cache run dry and the servo loads the emergency
braking profile, or the way-point stops advancing (a silent Brain link
freezes the planner's way-point, which the servo agent repeats until the
link is declared lost).  :class:`BrakeRecorder` watches the measured encoder
positions once per 500 Hz tick and, for every halt after motion, records

* ``moving_tick`` — the last tick at which some joint still moved at
  ``min_speed`` counts per tick or more;
* ``last_command_tick`` — the last command message that arrived up to then;
* ``starved_tick`` — the first tick of the braking profile, or -1 when the
  queue never ran dry (a planned end, or a frozen way-point);
* ``standstill_tick`` — the first tick at which no joint moves on in its
  direction of travel by more than ``still_counts`` counts per tick: the
  arm's velocity has reached zero (the position loop may then pull back a
  few counts of overshoot);
* ``settled_tick`` — the first of ``still_ticks`` ticks in a row in which no
  encoder moved more than ``still_counts`` counts per tick;
* ``peak_speed_counts_per_tick`` — the fastest joint during the motion.

Velocities are averaged over ``WINDOW`` ticks: the encoders are sampled on
another process's clock (the hardware's), so a single tick's difference
jitters.  Pure: the shell feeds it ticks and positions and prints each
record (one JSON object, on the servo's log).  Wall-clock time never enters.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from droid.subunits.reis.device import SERVO_HZ

SERVO_TICK_S = 1.0 / SERVO_HZ  # one servo tick [s] (droid.subunits.reis.device)
WINDOW = 4  # ticks over which velocity is averaged


@dataclass(frozen=True)
class BrakeEvent:
    last_command_tick: int
    moving_tick: int
    starved_tick: int
    standstill_tick: int
    settled_tick: int
    peak_speed_counts_per_tick: int

    @property
    def stop_ticks(self) -> int:
        """Servo ticks from the last command of the motion to zero velocity."""
        return self.standstill_tick - self.last_command_tick

    @property
    def stop_ms(self) -> float:
        """:attr:`stop_ticks` in milliseconds of servo time (2 ms a tick)."""
        return self.stop_ticks * SERVO_TICK_S * 1e3

    def as_dict(self) -> dict:
        d = asdict(self)
        d.update(stop_ticks=self.stop_ticks, stop_ms=round(self.stop_ms, 1))
        return d


class BrakeRecorder:
    """Turns the servo's per-tick state into :class:`BrakeEvent` records.  Pure.

    Plain Python on six integers (≈ 5 µs a tick): it runs inside the 500 Hz loop."""

    def __init__(self, still_counts: float = 1.0, still_ticks: int = 5, min_speed_counts_per_tick: float = 2.0):
        self.still = still_counts * WINDOW  # thresholds on the WINDOW-tick displacement
        self.still_ticks = still_ticks
        self.min_move = min_speed_counts_per_tick * WINDOW
        self._hist: list[tuple[int, ...]] = []
        self._last_cmd_tick = -1
        self._starved_since = -1
        self._moving = False
        self._reset_motion()

    def _reset_motion(self) -> None:
        self._dir: tuple[int, ...] | None = None
        self._peak = 0
        self._moving_tick = self._cmd_tick = -1
        self._stand_tick: int | None = None
        self._still_since: int | None = None

    def step(self, tick: int, command_arrived: bool, starved: bool, encoder_pos_counts,
             homing: bool = False) -> BrakeEvent | None:
        """One servo tick, after the core's step; returns a record when a halt completes.
        Homing moves (and the jump of the count frame when homing ends) are not recorded."""
        if homing:
            self._hist.clear()
            self._moving = False
            return None
        pos = tuple(int(x) for x in encoder_pos_counts)
        hist = self._hist
        hist.append(pos)
        if len(hist) > WINDOW + 1:
            del hist[0]
        n = len(hist) - 1
        # displacement over the window, scaled to WINDOW ticks (velocity x WINDOW)
        disp = [(p - o) * WINDOW // n for p, o in zip(pos, hist[0])] if n else [0] * len(pos)
        speed = [abs(d) for d in disp]
        if command_arrived:
            self._last_cmd_tick = tick
        if not starved:
            self._starved_since = -1
        elif self._starved_since < 0:
            self._starved_since = tick
        # moving: any joint at min_speed; once a halt has begun, only onwards in the
        # direction of travel (the position loop pulling back an overshoot is part of the halt)
        if self._moving and self._dir is not None:
            onwards = max(d * s for d, s in zip(disp, self._dir))
        else:
            onwards = max(speed, default=0)
        if onwards >= self.min_move:
            if not self._moving:
                self._moving = True
                self._reset_motion()
            self._dir = tuple((d > 0) - (d < 0) if abs(d) >= self.still else 0 for d in disp)
            self._peak = max(self._peak, max(speed))
            self._moving_tick, self._cmd_tick = tick, self._last_cmd_tick
            self._stand_tick, self._still_since = None, None
            return None
        if not self._moving:
            return None
        if self._stand_tick is None and all(d * s <= self.still for d, s in zip(disp, self._dir)):
            self._stand_tick = tick
        if max(speed, default=0) <= self.still:
            if self._still_since is None:
                self._still_since = tick
        else:
            self._still_since = None
        if self._stand_tick is None or self._still_since is None or tick - self._still_since + 1 < self.still_ticks:
            return None
        self._moving = False
        return BrakeEvent(self._cmd_tick, self._moving_tick, self._starved_since, self._stand_tick,
                          self._still_since, round(self._peak / WINDOW))
