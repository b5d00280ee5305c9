"""Periodic loops on absolute deadlines (docs/design.md §9).

Never ``sleep(period)``: it drifts.  :class:`PeriodicTimer` arms a Linux
timerfd on CLOCK_MONOTONIC with absolute expirations, so wake-ups stay on the
grid ``t0 + k * period`` whatever the loop body costs.  The fd can be waited on
directly (:meth:`wait`) or put in a ``zmq.Poller`` beside sockets.  Reading it
returns how many periods elapsed; more than one is an overrun, counted.

:func:`try_sched_fifo` asks for SCHED_FIFO when the cell file wants it and the
OS permits, and then locks the program's memory (:func:`lock_memory`); it never
fails the program.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import select
import struct
import sys
import time

CLOCK_MONOTONIC = 1
TFD_CLOEXEC = 0o2000000
TFD_NONBLOCK = 0o4000
TFD_TIMER_ABSTIME = 1


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [("it_interval", _Timespec), ("it_value", _Timespec)]


_libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
_libc.timerfd_create.argtypes = [ctypes.c_int, ctypes.c_int]
_libc.timerfd_settime.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Itimerspec),
                                  ctypes.POINTER(_Itimerspec)]


def _ts(ns: int) -> _Timespec:
    return _Timespec(ns // 1_000_000_000, ns % 1_000_000_000)


def now_ns() -> int:
    """CLOCK_MONOTONIC [ns] (the clock every DROID timestamp uses)."""
    return time.monotonic_ns()


class PeriodicTimer:
    """Absolute-deadline periodic timer (timerfd).

    ``period_ns`` [ns]; the first expiry is at ``start_ns`` (default: now + one
    period).  Statistics: ``cycles``, ``overruns`` (periods missed),
    ``lateness_ns`` of the last wake-up and ``lateness_max_ns``.
    """

    def __init__(self, period_ns: int, start_ns: int | None = None) -> None:
        if period_ns <= 0:
            raise ValueError("period must be > 0 ns")
        self.period_ns = int(period_ns)
        fd = _libc.timerfd_create(CLOCK_MONOTONIC, TFD_CLOEXEC | TFD_NONBLOCK)
        if fd < 0:
            err = ctypes.get_errno()
            raise OSError(err, os.strerror(err))
        self.fd = fd
        self.start_ns = start_ns if start_ns is not None else now_ns() + self.period_ns
        spec = _Itimerspec(_ts(self.period_ns), _ts(self.start_ns))
        if _libc.timerfd_settime(fd, TFD_TIMER_ABSTIME, ctypes.byref(spec), None) != 0:
            err = ctypes.get_errno()
            os.close(fd)
            raise OSError(err, os.strerror(err))
        self.expirations = 0  # total periods elapsed since start
        self.cycles = 0
        self.overruns = 0
        self.lateness_ns = 0
        self.lateness_max_ns = 0

    def fileno(self) -> int:
        return self.fd

    def consume(self) -> int:
        """After the fd polled readable: account for the expirations; returns how many.

        Returns 0 if nothing expired (spurious wake-up)."""
        try:
            data = os.read(self.fd, 8)
        except BlockingIOError:
            return 0
        n = struct.unpack("<Q", data)[0]
        t = now_ns()
        self.expirations += n
        self.cycles += 1
        if n > 1:
            self.overruns += n - 1
        deadline = self.start_ns + (self.expirations - 1) * self.period_ns
        self.lateness_ns = t - deadline
        if self.lateness_ns > self.lateness_max_ns:
            self.lateness_max_ns = self.lateness_ns
        return n

    def wait(self, timeout_s: float | None = None) -> int:
        """Block until the next expiry; returns the number of periods elapsed (0 on timeout)."""
        while True:
            r, _, _ = select.select([self.fd], [], [], timeout_s)
            if not r:
                return 0
            n = self.consume()
            if n:
                return n

    @property
    def deadline_ns(self) -> int:
        """The deadline of the most recent expiry [ns]."""
        return self.start_ns + max(self.expirations - 1, 0) * self.period_ns

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1

    def __enter__(self) -> "PeriodicTimer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: SCHED_FIFO priority of every program that asks for it (higher runs first) is declared
#: with the program in its device package (droid.brain.cell.registry.Program: sched "fifo",
#: priority); ``FIFO_PRIORITIES`` is the registry's view (module ``__getattr__`` below).
#: The servo's 500 Hz loop outranks everything; the watchdog must kick while the servo
#: lives; the world (the hardware) outranks the programs that drive it except the
#: servo side; the per-tick programs sit at the heartbeat's level; the sensor and
#: the encoder program below (docs/design.md §9; docs/architecture.md "Real time").
def __getattr__(name: str):
    if name == "FIFO_PRIORITIES":
        from droid.brain.cell.registry import fifo_priorities

        return fifo_priorities()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: The priority ceiling of the databases' semaphores (droid.brain.db.shmdb): above them all.
CEILING_PRIORITY = 61
DEFAULT_FIFO_PRIORITY = 50


MCL_CURRENT = 1  # <sys/mman.h>
MCL_FUTURE = 2
MCL_ONFAULT = 4  # Linux >= 4.4: lock pages as they are touched, do not populate whole mappings
M_TRIM_THRESHOLD = -1  # <malloc.h> mallopt parameters
M_MMAP_MAX = -4
_libc.mlockall.argtypes = [ctypes.c_int]
_libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]

#: heap touched once before locking, kept by malloc afterwards [MB] (the PREEMPT_RT
#: "pre-fault the heap" practice): a loop's first allocations find locked pages
HEAP_PREFAULT_MB = 4


def prefault_heap(mb: int = HEAP_PREFAULT_MB) -> None:
    """Keep freed heap with malloc (no trimming, no mmap'd blocks) and touch ``mb`` MB of it
    once, so allocations in the loop reuse pages that are already resident and locked."""
    _libc.mallopt(M_TRIM_THRESHOLD, -1)
    _libc.mallopt(M_MMAP_MAX, 0)
    block = bytearray(mb * 1024 * 1024)  # calloc'd from the brk heap, every page written
    for i in range(0, len(block), 4096):
        block[i] = 1
    del block


def lock_memory(prog: str = "droid") -> bool:
    """Lock this process's pages in RAM as it touches them (``mlockall`` with ``MCL_ONFAULT``).

    A real-time program must not take page faults in its loop (the PREEMPT_RT
    and cyclictest ``-m`` practice).  On this kind of host it matters more than
    usual: the kernel's proactive reclaim (DAMON ``pageout``) drops file pages
    -- the interpreter's and numpy's code -- that were not touched for a minute,
    so the first move after an idle minute read its code back from disk in
    the servo's or the world's loop: stalls of tens of ms under I/O load, the
    world's clock slipped seconds and moves halted short (issue 16).  Locked
    pages are never reclaimed.

    Only what the program touches is locked (issue 28): with ``MCL_ONFAULT`` the
    pages it has used by now (its imports, its start-up, a pre-faulted heap of
    :data:`HEAP_PREFAULT_MB`) and every page it touches later stay resident, but
    untouched reservations -- thread stacks of 8 MB, BLAS buffers, malloc arenas,
    the unused parts of every shared library -- are not populated.  Plain
    ``MCL_CURRENT | MCL_FUTURE`` populated all of them: 110-220 MB locked per program,
    2.1 GB for the default cell (docs/benchmarks.md "Footprint").  A kernel without
    ``MCL_ONFAULT`` (before 4.4) gets the old full lock.

    Returns False (with a warning) where the OS refuses, e.g. without root and with
    a small ``RLIMIT_MEMLOCK``; ``DROID_NO_MLOCK=1`` skips it (for measuring what it
    buys).
    """
    if os.environ.get("DROID_NO_MLOCK") == "1":
        return False
    prefault_heap()
    if _libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0:
        return True
    err = ctypes.get_errno()
    if err == 22 and _libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:  # EINVAL: no MCL_ONFAULT
        return True
    err = ctypes.get_errno() if err == 22 else err
    print(f"{prog}: memory not locked ({os.strerror(err)}); page faults may stall the loop",
          file=sys.stderr)
    return False


_libc.munlockall.argtypes = []


def normal_scheduler() -> None:
    """Put this process back on the normal scheduler (SCHED_OTHER) and unlock its memory.

    A program that asks for SCHED_FIFO is started on the normal scheduler and switches
    itself (:func:`try_sched_fifo`) once its imports are done.  Whatever starts cell
    programs calls this in the child before ``exec``: a child of a real-time parent
    inherits SCHED_FIFO, and sixteen programs importing numpy and Pinocchio at FIFO
    priority on two cores kept the running world off the CPU until the kernel's RT
    throttling stopped every real-time task for tens of ms (issue 16).  Best effort:
    never raises.
    """
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    try:
        if os.getpriority(os.PRIO_PROCESS, 0) == NICE_LEVEL:  # a "nice" program's level, not the user's
            os.setpriority(os.PRIO_PROCESS, 0, 0)
    except OSError:
        pass
    _libc.munlockall()


#: The nice level of a program declared ``sched = "nice"`` (droid.brain.cell.registry.Program): the
#: normal scheduler's weight of nice -10 is 9.3x that of nice 0, so a busy normal process beside
#: it delays its wake-ups by a scheduler slice (a few ms), never by the kernel's RT throttling.
NICE_LEVEL = -10


def freeze_heap(collect: bool = True) -> int:
    """Collect once, then move every object alive now into the garbage collector's permanent
    generation (:func:`gc.freeze`); returns how many objects it holds.

    CPython's cyclic collector runs inside whatever allocates the object that crosses its
    threshold, and a full (generation-2) pass walks every tracked object: after a program's
    imports (numpy, pyzmq, the cell file, the registry) that is 25,000-28,000 objects and took
    10-31 ms here (docs/benchmarks.md, issue 40, "Session 25: the soak again") -- a stall of the
    loop it lands in, at whatever priority the loop runs.  What a program imported and built before its loop
    lives as long as the program, so it is frozen once, before the loop: later passes walk only
    what the loop itself keeps (a tracker's rows, a seam map).  Reference counting still frees
    everything; only cycles among frozen objects are never collected.  ``DROID_NO_GC_FREEZE=1``
    skips it (for measuring what it buys).  ``collect=False`` freezes without the collection
    (instant: for a program already at real-time priority, whose start-up was collected and frozen
    once before it switched; what it built since lives as long as it does).
    """
    if os.environ.get("DROID_NO_GC_FREEZE") == "1":
        return gc.get_freeze_count()
    if collect:
        gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def try_sched_fifo(priority: int | None = None, *, wanted: bool = True, prog: str = "droid") -> bool:
    """Switch this process to SCHED_FIFO if wanted and permitted, at ``priority``
    (default: ``prog``'s entry in :data:`FIFO_PRIORITIES`), and lock its memory
    (:func:`lock_memory`).  A program the registry declares ``sched = "nice"`` (and no
    ``priority`` given) stays on the normal scheduler at :data:`NICE_LEVEL` instead, its
    memory locked likewise; returns False for it (it is not real-time).  Either way -- and also
    where SCHED_FIFO is not wanted -- the heap built so far is frozen first (:func:`freeze_heap`):
    this is where a program ends its start-up and begins its loop."""
    freeze_heap()
    if not wanted:
        return False
    if priority is None:
        from droid.brain.cell.registry import fifo_priorities, registry

        declared = registry().programs.get(prog)
        if declared is not None and declared.sched == "nice":
            lock_memory(prog)
            try:
                os.setpriority(os.PRIO_PROCESS, 0, NICE_LEVEL)
            except (PermissionError, OSError) as exc:
                print(f"{prog}: nice {NICE_LEVEL} not available ({exc}); running at normal priority",
                      file=sys.stderr)
            return False
        priority = fifo_priorities().get(prog, DEFAULT_FIFO_PRIORITY)
    # Lock first, on the normal scheduler: the old full mlockall paged in every mapping
    # (hundreds of MB) and, done at FIFO priority, kept the cell's running real-time
    # programs off the CPU while a new one started (a 205 ms stall of droid-sim, issue 16).
    lock_memory(prog)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError, AttributeError) as exc:
        print(f"{prog}: SCHED_FIFO not available ({exc}); running on the normal scheduler",
              file=sys.stderr)
        return False
    return True
