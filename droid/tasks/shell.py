"""What a task program's real-time shell shares (droid-seamtrack, droid-contact).

* :func:`run_on_ticks` and :class:`TickLoop`: the Brain's heartbeat ticks, one at a time, and
  the two ways a run ends from outside its cycle -- interrupted (SIGINT/SIGTERM, exit 130) or
  the heartbeat lost (no tick for :data:`HEARTBEAT_LOST_S`, exit 1);
* :func:`check_output_dirs`: the files a run writes have a directory to go to, checked
  before anything moves (exit 2);
* :func:`ready_then_run` and :func:`say_outcome`: a run's start (ready, the move to the start
  pose, interruptible) and the lines that say how it ended.
"""
from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import zmq

from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.runtime.program import Stop
from droid.brain.runtime.rt import try_sched_fifo
from droid.cli import EXIT_INTERRUPTED, EXIT_RUNTIME, BadInput
from droid.tasks.arm import STALE_GRACE_S, Interrupted

HEARTBEAT_LOST_S = STALE_GRACE_S  # no tick for this long [s]: the Brain's heartbeat is gone
#: The longest wait for a tick [s]: Stop and a lost heartbeat are seen this soon.
TICK_WAIT_S = 0.1


def check_output_dirs(*paths) -> None:
    """BadInput naming the first of ``paths`` (None: not asked for) whose directory does not exist."""
    for p in paths:
        if p is not None and Path(p).parent and not Path(p).parent.exists():
            raise BadInput(f"directory of {p} does not exist")


def ready_then_run(job, start: str | None, before: str, run) -> tuple[int, str]:
    """A run's start: ``job.check_ready()`` (refuses a faulted arm before anything moves), Stop
    installed, ``job.go_to_start(start)`` when a start is given, then ``run()``'s (exit code,
    reason) -- or (130, "interrupted before ``before``") when a signal came during the move
    (BrainArm.move stopped it where the arm stood: droid.tasks.arm.Interrupted)."""
    job.check_ready()
    Stop.install()
    if start:
        try:
            job.go_to_start(start)
        except Interrupted:
            pass
    if Stop.requested:
        return EXIT_INTERRUPTED, f"interrupted before {before}"
    return run()


def say_outcome(prog: str, why: str, summary_line: str, log=None, figure=None) -> None:
    """How a run ended: ``prog: stopped: why`` on stderr; the summary line, then the files written
    (``log: PATH``, ``figure: PATH``) on stdout."""
    print(f"{prog}: stopped: {why}", file=sys.stderr)
    print(summary_line)
    for label, p in (("log", log), ("figure", figure)):
        if p:
            print(f"{label}: {p}")


def run_on_ticks(cell, prog: str, loop) -> tuple[int, str]:
    """``loop(ticks)``'s (exit code, reason), ``ticks`` the heartbeat's subscriber, opened after
    asking for SCHED_FIFO (when the cell does: the loop is part of the cell's tick chain, below
    the remotes, so a loaded host does not stretch its delay -- a delay of 2+ cycles destabilises
    the seam tracking, §6.2.5) and closed after."""
    try_sched_fifo(wanted=cell.sched_fifo, prog=prog)
    ticks = TickSubscriber(zmq.Context.instance(), cell.heartbeat)
    try:
        return loop(ticks)
    finally:
        ticks.close()


class TickLoop:
    """A task's loop over the heartbeat ``ticks`` (a :class:`TickSubscriber`):
    ``for tick, now in loop:`` gives each tick as it arrives and ``time.monotonic()`` [s] at the
    wake-up; the loop ends when Stop is requested or no tick came for ``lost_s``, and
    :attr:`end` then holds (exit code, reason)."""

    def __init__(self, ticks, lost_s: float = HEARTBEAT_LOST_S) -> None:
        self.ticks, self.lost_s = ticks, lost_s
        self.end: tuple[int, str] | None = None

    def __iter__(self):
        last_tick_wall = time.monotonic()
        while True:
            if Stop.requested:  # between cycles: no half-written command
                self.end = EXIT_INTERRUPTED, f"interrupted ({signal.Signals(Stop.signum).name})"
                return
            t = self.ticks.wait(TICK_WAIT_S)
            now = time.monotonic()
            if t is None:
                if now - last_tick_wall > self.lost_s:
                    self.end = EXIT_RUNTIME, "heartbeat lost"
                    return
                continue
            last_tick_wall = now
            yield t, now
