"""The watchdog core (thesis §2.3, §4.1.2, §4.1.4).

The interface cards disable the servo amplifiers (a latched fault, cleared
only by a power cycle) unless both watchdog timer registers are rewritten in
time.  The watchdog program keeps them alive at >= 50 Hz -- but only while the
servo is alive: if the servo's heartbeat (its tick counter) stops changing for
``servo_liveness_steps`` watchdog steps, or the servo reports a fault, the
watchdog stops kicking for good and the hardware shuts the amplifiers down.
droid-watchdog sets ``servo_liveness_steps`` from the cell file's ``stale_ticks``
(:func:`liveness_steps`: the same silence, in time, as every other link).

A shell does, every 20 ms::

    kick = core.step(servo_heartbeat, servo_fault)
    if kick is not None:
        bus.write_watchdog(*kick)
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class WatchdogParams:
    rate_hz: float = 50.0  # kicking rate; the hardware timeout is 100 ms (droid.sim)
    servo_liveness_steps: int = 3  # heartbeat unchanged this many steps -> servo dead (60 ms)
    pattern: int = 0x5A5A  # XORed into the second register so the two never match

    def __post_init__(self) -> None:
        if self.rate_hz <= 0 or self.servo_liveness_steps < 1:
            raise ValueError("need rate_hz > 0 and servo_liveness_steps >= 1")


def liveness_steps(stale_ticks: int, heartbeat_hz: float, rate_hz: float = WatchdogParams.rate_hz) -> int:
    """The servo-liveness rule in watchdog steps for a cell whose links tolerate
    ``stale_ticks`` heartbeat periods of silence: the same time [s], rounded up (the cell
    file's ``stale_ticks``, one silence rule for every link; 3 ticks at 60 Hz -> 3 steps at
    50 Hz, 60 ms).  Issue 16: rules set against the host's measured stalls."""
    if stale_ticks < 1 or not heartbeat_hz > 0 or not rate_hz > 0:
        raise ValueError("need stale_ticks >= 1, heartbeat_hz > 0 and rate_hz > 0")
    return max(1, math.ceil(stale_ticks / heartbeat_hz * rate_hz - 1e-9))


class WatchdogCore:
    """Decides, each step, the two register values to write, or None (stop kicking)."""

    def __init__(self, params: WatchdogParams | None = None):
        self.params = params if params is not None else WatchdogParams()
        self._count = 0
        self._last_heartbeat: int | None = None
        self._stale_steps = 0
        self._dead = False

    # Alike in shape only to other read-only views (ServoCore's): the watchdog's own state.
    @property
    def servo_dead(self) -> bool:
        """Latched: the servo was declared dead and kicking has stopped."""
        return self._dead

    @property
    def kicks(self) -> int:
        """Number of kicks issued."""
        return self._count

    def declare_dead(self) -> None:
        """Stop kicking now (e.g. the shell saw the servo process exit)."""
        self._dead = True

    def rearm(self) -> None:
        """Resume supervision after the operator power-cycled the controller."""
        self._dead = False
        self._last_heartbeat = None
        self._stale_steps = 0

    def step(self, servo_heartbeat: int | None = None, servo_fault: bool = False) -> tuple[int, int] | None:
        """One watchdog period.  ``servo_heartbeat`` is the servo's tick counter
        (None: no servo supervision).  Returns (reg0, reg1) [u16] to write, or None."""
        if servo_fault:
            self._dead = True
        if servo_heartbeat is not None and not self._dead:
            if servo_heartbeat == self._last_heartbeat:
                self._stale_steps += 1
                if self._stale_steps >= self.params.servo_liveness_steps:
                    self._dead = True
            else:
                self._last_heartbeat = servo_heartbeat
                self._stale_steps = 0
        if self._dead:
            return None
        self._count += 1
        value = self._count & 0xFFFF
        return value, value ^ self.params.pattern
