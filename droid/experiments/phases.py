"""An opt-in report of where a ``droid-experiment run`` spends its time (issue 44 item 1).

Off unless the environment has ``DROID_PHASES=1``; then each phase boundary of a lockstep trial
prints one line to stderr::

    droid-phase {"phase": "homed", "t": 18342.117, "cpu_s": 2.841, "sim_s": 7.35, "trial": "1.12", "pid": 4242}

``t`` is ``time.monotonic()`` [s] (CLOCK_MONOTONIC: one clock for every process of the machine,
so a parent that notes the time before it starts the process gets the interpreter's start-up and
imports as ``t`` of ``main`` minus its own note), ``cpu_s`` this process's CPU time
(``time.process_time()``, user + system) [s], ``sim_s`` the trial scheduler's simulated time
since the trial began [s] (null before the scheduler exists and after the trial), ``trial`` the
trial's ID (null before it is known).  The boundaries, in this order for one trial:

=============  =====================================================================================
``main``       ``main()`` entered: the interpreter started and the command line's imports are done
``trial``      the trial function entered (``run_trial``, ``run_contact_trial``): arguments parsed,
               the experiments resolved, the job made
``built``      the welder built on the scheduler (the cell resolved and checked, the geometry, the
               arm's cores and twin; the lockstep builders imported); the fast arm: made
``homed``      the welder homed (the Reis: its servo's limit-switch search from the seeded power-up
               pose; the ABB: at once; the fast arm: no homing, ``sim_s`` as at ``built``)
``approached`` the welder moved to the start pose and settled
``ready``      everything else before the trial: the holder built, homed and at its holding pose
               (the GMF1), the tracking cycle, the sensors; the contact trial: the F/T twin biased
``tracked``    the trial's loop ended (its simulated seconds: ``sim_s`` here minus at ``ready``)
``figure``     the summary and the figure rendered (matplotlib imported when a figure is drawn)
``done``       the files and tables written, the last line printed: the command returns
=============  =====================================================================================

(with ``--jobs`` > 1 and several trials the lines of ``trial`` .. ``figure`` come from the pool's
processes, each with its ``pid``).  Nothing else changes: with the report on or off the trial's
files are byte for byte the same (tests/experiments/test_phases.py); bench/bench_trial_wall.py
reads the lines.
"""
from __future__ import annotations

import json
import os
import sys
import time

ENV = "DROID_PHASES"
PREFIX = "droid-phase"
PHASES = ("main", "trial", "built", "homed", "approached", "ready", "tracked", "figure", "done")

_trial: str | None = None


def enabled() -> bool:
    return os.environ.get(ENV) == "1"


def mark(phase: str, sched=None, trial: str | None = None) -> None:
    """Print the boundary ``phase`` (one of :data:`PHASES`) when the report is on; ``sched``: the
    trial's scheduler (its simulated time); ``trial``: the trial's ID, kept for later marks."""
    if not enabled():
        return
    global _trial
    if trial is not None:
        _trial = trial
    rec = {"phase": phase, "t": round(time.monotonic(), 6), "cpu_s": round(time.process_time(), 6),
           "sim_s": None if sched is None else sched.t_ns / 1e9, "trial": _trial, "pid": os.getpid()}
    print(f"{PREFIX} {json.dumps(rec)}", file=sys.stderr, flush=True)


def parse(text: str) -> list[dict]:
    """The phase records of a stderr text (other lines ignored), in order."""
    out = []
    for line in text.splitlines():
        if line.startswith(PREFIX + " "):
            out.append(json.loads(line[len(PREFIX) + 1:]))
    return out
