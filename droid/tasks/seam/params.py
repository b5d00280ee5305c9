"""The seam tracker's parameters and the ranges the programs accept (thesis §5.5, §6.1-6.2).

:class:`SeamParams` (one run's numbers, units in the names), the limits droid-seamtrack and
droid-experiment hold their options to (issue 16; docs/seamtrack.md, docs/experiments.md), the
tracking modes (docs/seamtrack.md "Modes") and the phases a cycle reports.  The tracker itself is
:mod:`droid.tasks.seam.core`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from droid.tasks.seam.guard import RUNAWAY_FACTOR

#: Largest index of the seam patch (the listing's MAX_QUEUE).  The patch
#: between the camera and the tool holds CAMERA_TO_TCP / (speed / 30 Hz)
#: frames: 750 at 4 mm/s with the 100 mm sensor lead; 2048 covers 1.5 mm/s.
MAX_QUEUE = 2048
#: Seam-tracking cycle rate [Hz]: every second tick of the 60 Hz heartbeat.
CYCLE_HZ = 30.0
#: Cycles without reading the sensor at the start (the listing's dead_zone).
DEAD_ZONE_CYCLES = 30
#: Consecutive invalid sensor cycles after which the seam counts as lost
#: (ASSUMED: the thesis stops by hand; 15 cycles = 0.5 s, 2 mm at 4 mm/s,
#: 32 mm at 64 mm/s of straight-on travel on zero data).
LOST_CYCLES = 15

#: Fastest travel speed a run accepts [mm/s] (ASSUMED: the thesis gives no Reis TCP speed
#: limit; plus mode tracks the step track at 400 mm/s in lockstep with the fast arm model,
#: whose joints are speed-limited as the servo's).  A faster request is refused up front.
MAX_SPEED_MM_S = 500.0

#: The ranges the programs accept (droid-seamtrack's options, droid-experiment's --length; issue 16):
#: a run length [mm] up to 10 m -- more than ten times the longest bundled seam (step_input, 760 mm
#: with its lead-in and -out) and far beyond the Reis's reach (ASSUMED: chosen, not from the thesis);
#: the proportional gains [-] 0..10 (the thesis runs 0.05..0.75, §6.2.5; above 1 a cycle corrects
#: more than the measured angle); cycle counts [30 Hz cycles] up to one hour of cycles.
MAX_RUN_LENGTH_MM = 10_000.0
MAX_GAIN = 10.0
MAX_CYCLES = 108_000

PHASE_DEAD_ZONE = "dead zone"  # the sensor is not read yet (still the initial section)
PHASE_INITIAL = "initial"  # the tool heads for the point where the sensor started
PHASE_TRACKING = "tracking"

#: Tracking modes (docs/seamtrack.md "Modes"): ``thesis`` -- the listing's tracker with the
#: patch read as §5.2 describes it (the tool projected onto the nearest patch segment, ``vel``
#: stepped along the patch); ``listing`` -- the literal port of the listing's ``interpolate()``;
#: ``plus`` -- the seam-map tracker of droid.tasks.seam.plus.
MODE_THESIS = "thesis"
MODE_LISTING = "listing"
MODE_PLUS = "plus"
MODES = (MODE_THESIS, MODE_LISTING, MODE_PLUS)



@dataclass(frozen=True)
class SeamParams:
    """Parameters of one seam-tracking run (units in the names)."""

    speed_mm_s: float
    yaw_gain: float = 0.15  # k_yaw (Experiment 1, §6.2.1)
    pitch_gain: float = 0.25  # k_pitch
    dead_zone_cycles: int = DEAD_ZONE_CYCLES
    lost_cycles: int = LOST_CYCLES
    length_mm: float = math.inf  # run length: tool travel after which the run ends (end of seam)
    delay_cycles: int = 0  # transport delay N [cycles] (0 = none)
    delay_at_mm: float = 150.0  # tool travel at which the delay is inserted [mm]
    max_queue: int = MAX_QUEUE
    cycle_hz: float = CYCLE_HZ
    runaway_factor: float = RUNAWAY_FACTOR  # 0 = no runaway guard
    mode: str = MODE_THESIS  # MODES
    accel_mm_s2: float = 200.0  # plus mode: travel acceleration limit from rest [mm/s^2]
    gap_mm: float = 30.0  # plus mode: longest stretch of seam bridged by extrapolation [mm]
    compliance: bool = True  # plus mode: correct the tool robot's poses for its drives' static deflection
    # (droid.tasks.seam.compliance; docs/seamtrack.md, "On the full arm")

    def __post_init__(self) -> None:
        for name in ("speed_mm_s", "yaw_gain", "pitch_gain", "delay_at_mm", "cycle_hz", "runaway_factor"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        if self.mode not in MODES:
            raise ValueError(f"unknown mode {self.mode!r} (known: {', '.join(MODES)})")
        if not (isinstance(self.accel_mm_s2, (int, float)) and self.accel_mm_s2 > 0):
            raise ValueError(f"acceleration must be > 0 mm/s^2, got {self.accel_mm_s2!r}")
        if not (isinstance(self.gap_mm, (int, float)) and self.gap_mm > 0):
            raise ValueError(f"the bridged gap must be > 0 mm, got {self.gap_mm!r}")
        why = speed_problem(self.speed_mm_s)
        if why:
            raise ValueError(why)
        if self.runaway_factor < 0:
            raise ValueError("runaway_factor must be >= 0")
        if self.cycle_hz <= 0:
            raise ValueError("cycle rate must be > 0 Hz")
        if not (self.length_mm > 0):
            raise ValueError(f"run length must be > 0 mm, got {self.length_mm!r}")
        if self.delay_at_mm < 0:
            raise ValueError("the delay point must be >= 0 mm")
        for name in ("dead_zone_cycles", "lost_cycles", "delay_cycles", "max_queue"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
        if self.lost_cycles < 1 or self.max_queue < 2:
            raise ValueError("lost_cycles must be >= 1 and max_queue >= 2")

    @property
    def step_mm(self) -> float:
        """The listing's ``vel``: distance the tool target advances per cycle [mm]."""
        return self.speed_mm_s / self.cycle_hz


def speed_problem(speed_mm_s: float) -> str | None:
    """Why a commanded travel speed [mm/s] cannot be tracked (None: it can): it must be > 0 and at
    most MAX_SPEED_MM_S.  SeamParams and the experiments' TrialConfig both ask here."""
    if speed_mm_s <= 0:
        return f"speed must be > 0 mm/s, got {speed_mm_s!r}"
    if speed_mm_s > MAX_SPEED_MM_S:
        return f"speed {speed_mm_s:g} mm/s is beyond what the arm can do (at most {MAX_SPEED_MM_S:g} mm/s)"
    return None
