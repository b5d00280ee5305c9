"""What every DROID program shell shares: common options, readiness, presence, stop.

* ``--cell FILE`` (default ``$DROID_CELL``, else the built-in simulated cell);
* ``--ready-fd N`` (set by ``droid-cell up``): the program writes one byte to
  fd N once it is ready to serve, then closes it — the launcher waits for that
  handshake instead of sleeping (docs/design.md §9);
* a :class:`Presence` record ``/droid.<cell>.proc.<key>`` that the program keeps
  fresh (state, pid, last tick, cycles, overruns), read by ``droid-cell status``;
* SIGTERM/SIGINT set :data:`Stop.requested`; loops check it and exit cleanly.
"""
from __future__ import annotations

import gc
import os
import signal
import sys
import time

from droid.brain.cell.cellfile import Cell, load_cell
from droid.brain.db.layouts import (LATENESS_NO_RECORD, PROC_FAILED, PROC_READY, PROC_STARTING, PROC_STATUS_LAYOUT,
                                 PROC_STOPPING)
from droid.brain.runtime.rt import freeze_heap
from droid.brain.db.shmdb import Database, db_name, unlink_database
from droid.cli import ArgumentParser, bounded_int


def parser(prog: str, description: str) -> ArgumentParser:
    p = ArgumentParser(prog=prog, description=description)
    p.add_argument("--cell", metavar="FILE", default=None,
                   help="cell file (default: $DROID_CELL, else the built-in simulated cell)")
    p.add_argument("--ready-fd", type=bounded_int(0, 1 << 20), default=None, help=argparse_suppress())
    return p


def argparse_suppress():
    import argparse

    return argparse.SUPPRESS


def open_cell(args) -> Cell:
    """Load the cell file a program was given; in a cell that wants SCHED_FIFO, the
    program's database accesses use the priority ceiling (droid.brain.db.shmdb)."""
    cell = load_cell(args.cell)
    use_cell(cell)
    return cell


def use_cell(cell: Cell) -> None:
    """Process-wide settings a cell asks for: the databases' priority ceiling."""
    from droid.brain.db import shmdb

    off = os.environ.get("DROID_NO_CEILING") == "1"  # for comparisons (bench/bench_under_load.py)
    shmdb.set_priority_ceiling(shmdb.CEILING_PRIORITY if cell.sched_fifo and not off else None)


def notify_ready(fd: int | None) -> None:
    """Complete the readiness handshake with the launcher (if any).  Every program calls it as
    its start-up ends and its loop begins, so the heap built so far is frozen here
    (droid.brain.runtime.rt.freeze_heap; collected first unless it was frozen once already, before the
    program switched to its real-time priority)."""
    freeze_heap(collect=gc.get_freeze_count() == 0)
    if fd is None:
        return
    try:
        os.write(fd, b"R")
    except OSError:
        pass
    try:
        os.close(fd)
    except OSError:
        pass


class Stop:
    """SIGTERM/SIGINT -> ``requested`` (checked by loops); ``signum``: which signal."""

    requested = False
    signum = 0

    @classmethod
    def install(cls) -> None:
        def handler(signum, frame):
            cls.requested = True
            cls.signum = signum

        signal.signal(signal.SIGTERM, handler)
        signal.signal(signal.SIGINT, handler)


def presence_key(prog: str, subunit: str | None = None) -> str:
    """Name part of a program's presence record, e.g. ``remote-arm1``."""
    key = prog.removeprefix("droid-")
    return f"{key}-{subunit}" if subunit else key


def process_age_s() -> float | None:
    """Seconds since this process started (Linux /proc), or None where unknown."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime_s = float(f.read().split()[0])
        return uptime_s - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


class RateWatch:
    """Does a program keep its rate?  The share of its periods it missed, over windows of
    :attr:`WINDOW_NS` (issue 28: no program starves silently).

    A tick-driven program (``last_tick`` > 0: agents, remotes, the planner) had as many
    periods in a window as heartbeat ticks went by, and missed the ticks it counts as
    overruns; a program on its own timer had ``cycles + overruns`` periods and missed
    ``overruns``.  A window with :attr:`LAG_PCT` or more missed makes it *lagging*: the
    program's log says so when it starts and at most every :attr:`REPEAT_S` while it lasts,
    and once when it keeps its rate again; ``droid-cell status`` shows it (LAGGING)."""

    WINDOW_NS = 2_000_000_000  # the window the share is taken over [ns]
    LAG_PCT = 5.0  # missing this share of its periods or more in a window is lagging [%]
    REPEAT_S = 30.0  # while lagging, the log repeats it at most this often [s]

    def __init__(self, display: str, out=None) -> None:
        self.display = display
        self.out = out  # where the log lines go (None: sys.stderr, the program's log)
        self.missed_pct = 0.0  # in the last whole window [%]
        self.lagging = False
        self._start = None  # (ns, last_tick, cycles, overruns) at the window's start
        self._since_ns = 0  # lagging since [ns]
        self._said_ns = 0  # the last lagging line [ns]

    def update(self, now_ns: int, last_tick: int, cycles: int, overruns: int) -> None:
        start = self._start
        if start is None or now_ns - start[0] < self.WINDOW_NS:
            if start is None:
                self._start = (now_ns, last_tick, cycles, overruns)
            return
        t0, tick0, cycles0, over0 = start
        self._start = (now_ns, last_tick, cycles, overruns)
        missed = max(0, overruns - over0)
        if last_tick > 0 and tick0 > 0:
            periods = max(0, last_tick - tick0)  # ticks that went by, missed ones included
        else:
            periods = max(0, cycles - cycles0) + missed
        pct = 100.0 * missed / periods if periods else 0.0
        self.missed_pct = pct
        window_s = (now_ns - t0) / 1e9
        lag = pct >= self.LAG_PCT
        if lag and not self.lagging:
            self._since_ns = self._said_ns = now_ns
            self._say(f"cannot keep its rate: missed {missed} of {periods} periods ({pct:.1f} %) "
                      f"in the last {window_s:.1f} s")
        elif lag and (now_ns - self._said_ns) / 1e9 >= self.REPEAT_S:
            self._said_ns = now_ns
            self._say(f"still cannot keep its rate: missed {missed} of {periods} periods ({pct:.1f} %) "
                      f"in the last {window_s:.1f} s; lagging for {(now_ns - self._since_ns) / 1e9:.0f} s")
        elif not lag and self.lagging:
            self._say(f"keeps its rate again ({pct:.1f} % missed in the last {window_s:.1f} s; "
                      f"lagged for {(now_ns - self._since_ns) / 1e9:.0f} s)")
        self.lagging = lag

    def _say(self, text: str) -> None:
        print(f"{self.display}: {text}", file=self.out or sys.stderr, flush=True)


class Presence:
    """A program's own record in ``/droid.<cell>.proc.<key>`` (for droid-cell status)."""

    UPDATE_NS = 100_000_000  # refresh at most every 100 ms
    SLOW_START_S = 10.0  # a start-up slower than this is said in the program's log [s]

    def __init__(self, cell: str, key: str, display: str) -> None:
        self.display = display
        self._created = time.monotonic()
        self.name = db_name(cell, "proc", key)
        self.db = Database(self.name, PROC_STATUS_LAYOUT, create=True)
        self.db.update(name=display.encode()[:31], pid=os.getpid(), state=PROC_STARTING,
                       updated_ns=time.monotonic_ns(), lateness_max_ns=LATENESS_NO_RECORD)
        self._last = 0
        self.rate = RateWatch(display)

    def say(self, text: str) -> None:
        """One line in the program's log, under its name (as RateWatch says LAGGING)."""
        print(f"{self.display}: {text}", file=sys.stderr, flush=True)

    def due(self) -> bool:
        """Whether :meth:`beat` would write now: a loop serving many subunits asks before it sums
        their figures, instead of summing on every wake-up for a beat that returns at once."""
        return time.monotonic_ns() - self._last >= self.UPDATE_NS

    def beat(self, last_tick: int = 0, cycles: int = 0, overruns: int = 0,
             lateness_max_ns: int = LATENESS_NO_RECORD, *, bad_frames: int = 0, force: bool = False) -> None:
        """Refresh the record: last heartbeat tick, loop cycles, overruns (missed deadlines
        or ticks), worst lateness [ns] (``LATENESS_NO_RECORD`` when the loop keeps none), malformed messages dropped so far; and whether the
        program keeps its rate (:class:`RateWatch`: ``missed_pct``, ``lagging``)."""
        now = time.monotonic_ns()
        if not force and now - self._last < self.UPDATE_NS:
            return
        self._last = now
        rate = self.rate
        rate.update(now, last_tick, cycles, overruns)
        self.db.update(last_tick=last_tick, updated_ns=now, cycles=cycles, overruns=overruns,
                       lateness_max_ns=lateness_max_ns, bad_frames=bad_frames,
                       missed_pct=rate.missed_pct, lagging=int(rate.lagging))

    def set_state(self, state: int) -> None:
        self.db.update(state=state, updated_ns=time.monotonic_ns())

    def ready(self) -> None:
        self.set_state(PROC_READY)
        since_record = time.monotonic() - self._created
        age = process_age_s()
        if since_record > self.SLOW_START_S or (age is not None and age > self.SLOW_START_S):
            # a slow start is named in the log: before the record (imports, locking memory)
            # or after it (opening devices, sockets) -- issue 16's intermittent start-up stall
            print(f"{self.display}: ready {age if age is not None else float('nan'):.1f} s after the "
                  f"process started, {since_record:.1f} s after it registered", file=sys.stderr, flush=True)

    def close(self, failed: bool = False) -> None:
        """Clean exit removes the record; a failure leaves it marked for status."""
        if failed:
            self.set_state(PROC_FAILED)
            self.db.close()
        else:
            self.set_state(PROC_STOPPING)
            self.db.close()
            unlink_database(self.name)


def subunit_program(prog: str, description: str, argv=None, *, arm: bool = False, options=None,
                    example: str = "arm1", several: bool = False, one_host: bool = False):
    """Common start of a program serving one subunit: parse ``[--cell FILE] SUBUNIT``,
    load the cell, check the subunit (an arm if ``arm``), install the stop handler.
    ``options(ap)`` adds the program's own options to the parser.  ``several``: ``SUBUNIT...``,
    each named once, and ``sub`` is their list; ``one_host``: all of them on one host (a process
    serving a host's subunits, ``[cell] share``).

    Returns ``(args, cell, sub)``; bad input raises BadInput (exit 2)."""
    from droid.cli import BadInput

    ap = parser(prog, description)
    ap.add_argument("subunit", nargs="+" if several else None,
                    help=f"arm subunit, e.g. {example}" if arm else f"subunit name, e.g. {example}")
    if options is not None:
        options(ap)
    args = ap.parse_args(argv)
    cell = open_cell(args)
    names = args.subunit if several else [args.subunit]
    subs = [cell.subunit(n) for n in names]
    twice = [n for i, n in enumerate(names) if n in names[:i]]
    if twice:
        raise BadInput(f"subunit {twice[0]!r} named twice")
    for sub in subs if arm else ():
        if not sub.is_arm:
            raise BadInput(f"{sub.name} is a {sub.cls} subunit, not an arm")
    for sub in subs[1:] if one_host else ():
        if sub.host != subs[0].host:
            raise BadInput(f"{sub.name} is on host {sub.host!r} and {subs[0].name} on {subs[0].host!r}: "
                           "one process serves the subunits of one host")
    Stop.install()
    return args, cell, subs if several else subs[0]


def shared_key(prog: str, subs) -> str:
    """The presence key of ``prog`` serving ``subs``: ``agent-joy`` for one subunit, ``agents-HOST``
    for the process that serves several of a host (``[cell] share``; the plural names no program,
    so it is never a one-subunit key)."""
    if len(subs) == 1:
        return presence_key(prog, subs[0].name)
    host = "".join(c if c.isascii() and (c.isalnum() or c in "-_") else "_" for c in subs[0].host)
    return f"{presence_key(prog)}s-{host}"


def serving_presence(cell, prog: str, subs) -> "Presence":
    """The presence record of ``prog`` serving ``subs`` (:func:`shared_key`), shown as ``PROG NAME...``."""
    return Presence(cell.name, shared_key(prog, subs), f"{prog} {' '.join(s.name for s in subs)}")


def close_all(*resources) -> None:
    """Close what a shell opened, in this order, at its exit (the ``finally`` of ``main``).

    Each item is an object with ``close()``, a callable (e.g. a ZeroMQ
    context's ``term``), or None for what was never opened.  Every item is
    closed even when an earlier one raised; the first error is raised after.
    """
    first: BaseException | None = None
    for r in resources:
        if r is None:
            continue
        try:
            r.close() if hasattr(r, "close") else r()
        except BaseException as exc:  # noqa: BLE001 - close the rest first, then re-raise
            first = first or exc
    if first is not None:
        raise first


class ErrorLine:
    """A device error said once on stderr each time it changes (a persisting fault is not repeated).

    ``update(error)`` prints ``PROG: <prefix><error>`` when ``error`` differs
    from the last one and is not empty.
    """

    def __init__(self, prog: str, prefix: str = "") -> None:
        self.prog = prog
        self.prefix = prefix
        self.last = ""

    def update(self, error: str) -> None:
        if error != self.last:
            self.last = error
            if error:
                print(f"{self.prog}: {self.prefix}{error}", file=sys.stderr)
