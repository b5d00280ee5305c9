"""The transport-delay buffer of the transport-delay experiments (thesis §6.2.5, Table 6.3 3.21-3.28).

"A buffer corresponding to the size of Transport Delay cycles is created at
the start of the program.  At a fixed point the delay is executed.  This
causes the sensor data to be set to zero for the number of Transport Delay
cycles.  The actual data is stored in the buffer.  When the delay is over,
the Seam Tracking resumes but data which is delayed by the number of
Transport Delay cycles is used instead.  Actual data from the sensor is then
routed to the rotating buffer and delayed before being used."

:class:`TransportDelay` does exactly that, per 30 Hz seam-tracking cycle:
before the trigger (the tool has travelled ``at_mm``) readings pass through;
from the trigger cycle on every reading enters a FIFO of ``cycles`` entries;
during the first ``cycles`` cycles the output is a zero reading, afterwards
the reading of ``cycles`` cycles ago.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

#: Delay states reported per cycle.
DELAY_OFF = "off"  # no delay configured, or not triggered yet: the reading passes through
DELAY_ZEROED = "zeroed"  # the first N cycles after the trigger: zero data
DELAY_DELAYED = "delayed"  # from then on: the reading of N cycles ago


@dataclass(frozen=True)
class Reading:
    """One lead-sensor reading in the sensor frame S (docs/mvs.md).

    ``x_mm`` depth, ``y_mm`` lateral, ``roll_rad`` the surface roll about S's
    z; ``valid`` False for an invalid reading (Table 3.3: homed = 1).
    ``zeroed`` marks the zero data the transport-delay buffer inserts (valid
    zeros, not a sensor failure).  ``stamp_tick``: the instant the frame was
    captured [heartbeat ticks] when the reading carries it (a stamped sensor
    line, or the lockstep harness); None: the tracking cycle assumes its
    Status tick minus ``SENSOR_LAG_TICKS`` (droid.tasks.seam.cycle).

    Not :class:`droid.brain.plumbing.sensor_line.LineReading` (one parsed "x,y,roll"
    line, stamped in ms mod the stamp modulo): the tracker reads the Brain's
    sensor Status, not the line.
    """

    x_mm: float = 0.0
    y_mm: float = 0.0
    roll_rad: float = 0.0
    valid: bool = True
    zeroed: bool = False
    stamp_tick: float | None = None  # capture instant [heartbeat ticks], when known (issue 12)


ZERO_READING = Reading(0.0, 0.0, 0.0, True, True)
INVALID_READING = Reading(0.0, 0.0, 0.0, False)


class TransportDelay:
    """Zero for ``cycles`` cycles once the tool has travelled ``at_mm``, then delay by ``cycles``."""

    def __init__(self, cycles: int = 0, at_mm: float = 150.0) -> None:
        if cycles < 0:
            raise ValueError("transport delay: cycles must be >= 0")
        if not at_mm >= 0:
            raise ValueError("transport delay: the trigger distance must be >= 0 mm")
        self.cycles = int(cycles)
        self.at_mm = float(at_mm)
        self.triggered_at_cycle: int | None = None
        self._fifo: deque[Reading] = deque()
        self._cycle = 0

    @property
    def triggered(self) -> bool:
        return self.triggered_at_cycle is not None

    def filter(self, reading: Reading, travel_mm: float) -> tuple[Reading, str]:
        """The reading to use this cycle and the delay state (``DELAY_*``)."""
        cycle = self._cycle
        self._cycle += 1
        if self.cycles == 0:
            return reading, DELAY_OFF
        if not self.triggered:
            if travel_mm < self.at_mm:
                return reading, DELAY_OFF
            self.triggered_at_cycle = cycle
        self._fifo.append(reading)
        if len(self._fifo) <= self.cycles:
            return ZERO_READING, DELAY_ZEROED
        return self._fifo.popleft(), DELAY_DELAYED
