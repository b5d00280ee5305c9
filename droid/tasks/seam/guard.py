"""The tool's travel and the two stops it decides (``runaway``, ``end of seam``), kept by every
tracker core (thesis, listing, plus): :class:`TravelGuard` (an addition; docs/seamtrack.md,
"Reading the thesis"; docs/safety.md)."""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from droid.tasks.seam.stops import STOP_END, STOP_RUNAWAY

#: Runaway guard (an addition): after the dead zone, the tool moving more than
#: RUNAWAY_FACTOR times the commanded speed over the last RUNAWAY_WINDOW cycles (and
#: more than RUNAWAY_MIN_MM) stops the run -- an oscillating, unstable loop (long
#: delays, §6.2.5) or an arm that does not follow.  Normal tracking runs at ~0.5x the
#: speed; the real-time arm moves in bursts (up to ~0.8 mm per 60 Hz tick at the wrist
#: centre) and, on a busy host, lurches once by 20-30 mm in under a second and recovers:
#: the guard looks at two seconds, so it stops sustained oscillation, not one lurch.
RUNAWAY_FACTOR = 4.0
RUNAWAY_WINDOW = 60
RUNAWAY_MIN_MM = 10.0
#: The run length of the thesis and listing modes is the measured tool's path resampled in
#: straight chords of this length [mm] (``TravelGuard``): consecutive chords share their end
#: points, so the tool point's jitter along the path cancels, and a jitter of amplitude a
#: across it adds only ~2 a^2 / TRAVEL_CHORD_MM a chord (0.3 mm of stick-slip: 0.7 %), where the
#: per-cycle sum adds ~2 a every cycle (the full arm's runs ended at 276-602 mm of 700 with it).
#: A chord shortens an arc of radius R by CHORD^2 / (24 R^2): 0.17 % on the R25 arc.
TRAVEL_CHORD_MM = 5.0



class TravelGuard:
    """The tool's travel and the two stops it decides, as every tracker core (thesis, listing, plus) keeps them.

    :meth:`step` takes the tool's position this cycle (holder's wrist frame
    [mm]), advances ``travel_mm`` and says why the run must stop (None: it need
    not).  ``travel_mm`` -- the run length, the delay trigger (§6.2.5) -- is the
    caller's ``progress_mm`` when it gives one (plus mode: the tool's foot on its
    seam map), else the tool's path in straight chords of TRAVEL_CHORD_MM
    (thesis and listing modes: a new chord end each time the tool is that far
    from the last one, plus the straight distance to the open end; never
    decreasing) -- not the per-cycle sum ``path_mm``, which the tool point's
    jitter on a stick-slip arm makes run ahead of the seam (an addition: the
    listing's stop is by hand, §6.2.5).  The stops: ``runaway`` when, outside the dead zone, the tool moved more than
    ``runaway_factor`` times the commanded step per cycle over the last
    RUNAWAY_WINDOW cycles (and more than RUNAWAY_MIN_MM) -- an oscillating,
    unstable loop (docs/safety.md); a late Status counts as ``elapsed_cycles``
    cycles of time; ``end of seam`` when ``length_mm`` is travelled.
    """

    def __init__(self, params: "SeamParams") -> None:
        self.p = params
        self.travel_mm = 0.0  # the run's progress: the chord path, or the caller's progress_mm
        self.path_mm = 0.0  # the summed path of the tool point [mm] (the runaway guard's measure)
        self.chords_mm = 0.0  # the closed chords' length [mm]
        self.chord_end: np.ndarray | None = None  # where the open chord starts (holder's wrist frame, mm)
        self.last_tool: np.ndarray | None = None
        self.recent: deque = deque(maxlen=RUNAWAY_WINDOW)  # (moved mm, cycles)
        # the same two columns apart, so the guard's sums run over a deque, not a generator (the
        # same numbers in the same order: the same bits)
        self._recent_mm: deque = deque(maxlen=RUNAWAY_WINDOW)
        self._recent_cycles: deque = deque(maxlen=RUNAWAY_WINDOW)

    def step(self, tool, elapsed_cycles: float, guard_runaway: bool,
             progress_mm: float | None = None) -> tuple[str, str] | None:
        """One cycle's tool position [mm]; (stop reason, detail) or None.

        ``progress_mm``: the tool's progress along the seam as the caller knows it (plus mode:
        the arc length of the tool's foot on the seam map); when given it, not the summed path,
        is ``travel_mm`` (never decreasing) -- the summed path of the measured tool runs ahead
        of the seam coordinate on an arm whose tool point jitters across the seam."""
        moved_mm = 0.0
        if self.last_tool is not None:
            d = tool - self.last_tool
            moved_mm = math.sqrt(float(d.dot(d)))  # np.linalg.norm(d), without its overhead
            self.path_mm += moved_mm
        self.last_tool = tool
        if progress_mm is None:
            progress_mm = self._chord_travel(tool)
        self.travel_mm = max(self.travel_mm, float(progress_mm))
        if guard_runaway and self.p.runaway_factor > 0:
            cycles = max(1.0, elapsed_cycles)
            self.recent.append((moved_mm, cycles))
            self._recent_mm.append(moved_mm)
            self._recent_cycles.append(cycles)
            moved = sum(self._recent_mm)
            limit_mm = max(self.p.runaway_factor * self.p.step_mm * sum(self._recent_cycles), RUNAWAY_MIN_MM)
            if moved > limit_mm:
                return STOP_RUNAWAY, f"the tool moved {moved:.1f} mm in {len(self.recent)} cycles " \
                                     f"(limit {limit_mm:.1f} mm)"
        if self.travel_mm >= self.p.length_mm:
            return STOP_END, f"run length {self.p.length_mm:g} mm reached"
        return None

    def _chord_travel(self, tool) -> float:
        """The tool's path in chords of TRAVEL_CHORD_MM to ``tool`` [mm] (see the class)."""
        if self.chord_end is None:
            self.chord_end = np.array(tool, float)
            return 0.0
        d = tool - self.chord_end
        open_mm = math.sqrt(float(d.dot(d)))
        if open_mm >= TRAVEL_CHORD_MM:
            self.chords_mm += open_mm
            self.chord_end = np.array(tool, float)
            open_mm = 0.0
        return self.chords_mm + open_mm
