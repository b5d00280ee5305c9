"""Databases: one fixed-layout record in a POSIX shared-memory object + a named semaphore.

Thesis §3.3: "a memory area is created and made globally accessible ... Exclusive
access to this is granted to the program which has ownership of the semaphore".
docs/design.md §3 and §9 add what a Python cell on Linux needs:

* names carry the cell: ``/droid.<cell>.<subunit>.<area>`` (see :func:`db_name`),
  objects are created with mode 0600;
* every acquire has a timeout (:class:`LockTimeout`, a runtime failure);
* the semaphore holder writes its pid into the header; a waiter that times out
  on a holder that is dead takes the lock over.  Exactly one waiter does so: the
  take-over itself is guarded by a second semaphore ``<name>.rec`` acquired
  without blocking, and the winner re-checks the holder under it.  The record's
  ``FLAG_RECOVERED`` bit tells everyone it happened;
* attaching to a record whose magic, kind, version or size differs is refused
  with :class:`~droid.brain.db.layouts.LayoutError`.

:class:`MemoryDatabase` has the same interface without shared memory, for the
lockstep mode (everything in one process on virtual time).
"""
from __future__ import annotations

import contextlib
import mmap
import os
import re
import struct
import time
from typing import Iterator

import numpy as np
import posix_ipc

from droid.brain.runtime import rt

from droid.cli import BadInput, RuntimeFailure
from droid.brain.db.layouts import (
    FLAG_RECOVERED,
    HOLDER_PID_OFFSET,
    Layout,
    SEQ_OFFSET,
    WRITER_PID_OFFSET,
    check_header,
    new_record,
)

SHM_MODE = 0o600
DEFAULT_TIMEOUT_S = 0.5  # a locked access takes microseconds; 0.5 s means something is wrong
POLL_SLICE_S = 0.02  # how often a waiter looks at the recorded holder
SHM_DIR = "/dev/shm"
_NAME_PART = re.compile(r"^[A-Za-z0-9_-]{1,40}$")
_I32 = struct.Struct("<i")
_U64 = struct.Struct("<Q")


class LockTimeout(RuntimeFailure):
    """The database semaphore was not obtained within the timeout."""


class NoDatabase(RuntimeFailure):
    """The shared-memory object does not exist (is the cell up?)."""


def check_name_part(part: str, what: str) -> str:
    """Validate a cell/subunit/area name part (letters, digits, '-', '_')."""
    if not isinstance(part, str) or not _NAME_PART.match(part):
        raise BadInput(f"invalid {what} name {part!r}: use 1-40 letters, digits, '-' or '_'")
    return part


def db_name(cell: str, *parts: str) -> str:
    """POSIX name of a database: ``/droid.<cell>.<part>.<part>...``."""
    check_name_part(cell, "cell")
    for p in parts:
        check_name_part(p, "database")
    return "/droid." + ".".join((cell,) + tuple(parts))


def pid_alive(pid: int) -> bool:
    """True if a process with this pid exists (zombies count as dead)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


# -- the priority ceiling (issue 16) ---------------------------------------------------
#: A process that holds a database semaphore runs at this SCHED_FIFO priority while it
#: holds it (the immediate priority-ceiling protocol), when its cell asks for SCHED_FIFO.
#: POSIX named semaphores have no priority inheritance: without the ceiling a task or
#: droid-snoop at normal priority, preempted by busy processes while it holds a Status
#: semaphore for a 1 us copy, blocked the real-time remote, servo agent or the servo's
#: own presence record for tens of ms -- the stalls that failed homing under load.
#: CEILING_PRIORITY (droid.brain.runtime.rt, 61) is above every program's own priority (servo 60).
_ceiling: int | None = None
CEILING_PRIORITY = rt.CEILING_PRIORITY


def set_priority_ceiling(priority: int | None) -> None:
    """Use the priority ceiling in this process from now on (None: never).  Called when a
    program opens a cell that wants SCHED_FIFO; silently off where the OS refuses it."""
    global _ceiling
    _ceiling = priority


def _raise_to_ceiling():
    """Enter the ceiling; returns what to restore, or None (no change was made)."""
    global _ceiling
    if _ceiling is None:
        return None
    try:
        policy = os.sched_getscheduler(0)
        prio = os.sched_getparam(0).sched_priority
        if policy in (os.SCHED_FIFO, os.SCHED_RR) and prio >= _ceiling:
            return None
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(_ceiling))
    except (PermissionError, OSError):
        _ceiling = None  # not permitted here: the normal scheduler, as without it
        return None
    return policy, prio


def _leave_ceiling(saved) -> None:
    if saved is not None:
        try:
            os.sched_setscheduler(0, saved[0], os.sched_param(saved[1]))
        except OSError:
            pass


class Database:
    """One record of ``layout`` in shared memory, guarded by a named semaphore.

    ``create=True`` makes a fresh object (replacing a stale one of the same
    name left by a crashed cell: docs/design.md §9 "recreate at cell start");
    otherwise the object must exist and match the layout.
    """

    def __init__(self, name: str, layout: Layout, *, create: bool = False,
                 timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        self.name = name
        self.layout = layout
        self.timeout_s = timeout_s
        self._pid = os.getpid()
        self._mm: mmap.mmap | None = None
        size = layout.size
        if create:
            unlink_database(name)
            shm = posix_ipc.SharedMemory(name, posix_ipc.O_CREX, mode=SHM_MODE, size=size)
            self._sem = posix_ipc.Semaphore(name, posix_ipc.O_CREX, mode=SHM_MODE, initial_value=1)
            self._rec = posix_ipc.Semaphore(name + ".rec", posix_ipc.O_CREX, mode=SHM_MODE,
                                            initial_value=1)
        else:
            try:
                shm = posix_ipc.SharedMemory(name)
                self._sem = posix_ipc.Semaphore(name)
                self._rec = posix_ipc.Semaphore(name + ".rec")
            except posix_ipc.ExistentialError:
                raise NoDatabase(f"database {name} does not exist (is the cell up?)") from None
        try:
            if shm.size < HEADER_MIN:
                raise_short(name, shm.size, size)
            self._mm = mmap.mmap(shm.fd, shm.size)
        finally:
            shm.close_fd()
        if create:
            self._mm[:size] = new_record(layout).tobytes()
            _I32.pack_into(self._mm, WRITER_PID_OFFSET, self._pid)
        else:
            try:
                check_header(self._mm, layout, f"database {name}")
            except Exception:
                self.close()
                raise
        self._view = np.ndarray((), dtype=layout.dtype, buffer=self._mm)

    # -- locking ---------------------------------------------------------
    def _acquire(self) -> None:
        deadline = time.monotonic() + self.timeout_s
        orphan_seen = False
        while True:
            try:
                self._sem.acquire(POLL_SLICE_S)
                _I32.pack_into(self._mm, HOLDER_PID_OFFSET, self._pid)
                return
            except posix_ipc.BusyError:
                pass
            holder = _I32.unpack_from(self._mm, HOLDER_PID_OFFSET)[0]
            if holder and holder != self._pid and not pid_alive(holder):
                if self._take_over(holder):
                    return
            now = time.monotonic()
            if now >= deadline:
                if holder == 0 and not orphan_seen:
                    # Taken with no holder recorded for a whole timeout: the holder died
                    # between sem_wait and writing its pid (or between clearing it and
                    # sem_post).  Try once more, then take it over.
                    orphan_seen = True
                    deadline = now + self.timeout_s
                    continue
                if holder == 0 and orphan_seen and self._take_over(0):
                    return
                raise LockTimeout(
                    f"database {self.name}: semaphore not obtained in {self.timeout_s:g} s "
                    f"(held by pid {holder or 'unknown'})"
                )

    def _take_over(self, dead_pid: int) -> bool:
        """Take the lock from a dead holder; True if this process now holds it."""
        try:
            self._rec.acquire(0)
        except posix_ipc.BusyError:
            return False  # another waiter is recovering
        try:
            holder = _I32.unpack_from(self._mm, HOLDER_PID_OFFSET)[0]
            if holder != dead_pid or self._sem.value != 0:
                return False  # it moved on meanwhile
            if dead_pid and pid_alive(dead_pid):
                return False
            _I32.pack_into(self._mm, HOLDER_PID_OFFSET, self._pid)
            flags = int(self._view["flags"])
            self._view["flags"] = flags | FLAG_RECOVERED
            return True  # we inherit the taken semaphore: release() posts it
        finally:
            self._rec.release()

    def _release(self) -> None:
        _I32.pack_into(self._mm, HOLDER_PID_OFFSET, 0)
        self._sem.release()

    @contextlib.contextmanager
    def locked(self) -> Iterator[np.ndarray]:
        """Hold the semaphore; yields the live 0-d record view (writes bump seq)."""
        saved = _raise_to_ceiling()
        try:
            self._acquire()
            try:
                yield self._view
            finally:
                self._release()
        finally:
            _leave_ceiling(saved)

    # -- access ----------------------------------------------------------
    def read(self) -> np.ndarray:
        """A consistent copy of the record (0-d structured array)."""
        saved = _raise_to_ceiling()
        try:
            self._acquire()
            try:
                raw = bytearray(self._mm[: self.layout.size])  # one memcpy; numpy's copy is 20x slower
            finally:
                self._release()
        finally:
            _leave_ceiling(saved)
        return np.ndarray((), dtype=self.layout.dtype, buffer=raw)

    def write(self, rec: np.ndarray | None = None, **fields) -> int:
        """Write a whole record (payload only; header kept) and/or fields; returns seq."""
        with self.locked():
            return self._write_locked(rec, fields)

    def _write_locked(self, rec, fields) -> int:
        v = self._view
        if rec is not None:
            hdr = self._mm[:32]
            self._mm[: self.layout.size] = np.asarray(rec, dtype=self.layout.dtype).tobytes()
            self._mm[:32] = hdr
        for k, val in fields.items():
            v[k] = val
        return self._bump()

    def update(self, **fields) -> int:
        """Set some fields under the lock; returns the new seq."""
        return self.write(None, **fields)

    def _bump(self) -> int:
        seq = _U64.unpack_from(self._mm, SEQ_OFFSET)[0] + 1
        _U64.pack_into(self._mm, SEQ_OFFSET, seq)
        _I32.pack_into(self._mm, WRITER_PID_OFFSET, self._pid)
        return seq

    def mark_written(self) -> int:
        """Inside :meth:`locked`: count the changes made through the view as one write."""
        return self._bump()

    @property
    def seq(self) -> int:
        """Write counter (read without the lock: a hint, not a snapshot)."""
        return _U64.unpack_from(self._mm, SEQ_OFFSET)[0]

    def raw_bytes(self) -> bytes:
        """The whole record as bytes (locked copy)."""
        with self.locked():
            return bytes(self._mm[: self.layout.size])

    def close(self) -> None:
        """Unmap and close the semaphores (the objects stay for others)."""
        if getattr(self, "_view", None) is not None:
            self._view = None
        if self._mm is not None:
            try:
                self._mm.close()
            except BufferError:
                pass  # a view still exported; the mapping goes with the process
            self._mm = None
        for sem in (getattr(self, "_sem", None), getattr(self, "_rec", None)):
            if sem is not None:
                try:
                    sem.close()
                except posix_ipc.Error:
                    pass

    def unlink(self) -> None:
        """Close and remove the objects from the system."""
        self.close()
        unlink_database(self.name)

    def __enter__(self) -> "Database":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


HEADER_MIN = 32


def raise_short(name: str, got: int, want: int) -> None:
    from droid.brain.db.layouts import LayoutError

    raise LayoutError(f"database {name}: object is {got} bytes, expected {want}")


def unlink_database(name: str) -> None:
    """Remove a database's shm object and semaphores if they exist."""
    for fn in (posix_ipc.unlink_shared_memory, posix_ipc.unlink_semaphore):
        try:
            fn(name)
        except posix_ipc.ExistentialError:
            pass
    try:
        posix_ipc.unlink_semaphore(name + ".rec")
    except posix_ipc.ExistentialError:
        pass


def cell_objects(cell: str) -> list[str]:
    """Every /dev/shm entry belonging to ``cell`` (shm objects and semaphores)."""
    check_name_part(cell, "cell")
    prefixes = (f"droid.{cell}.", f"sem.droid.{cell}.")
    try:
        return sorted(n for n in os.listdir(SHM_DIR) if n.startswith(prefixes))
    except FileNotFoundError:
        return []


def remove_cell_objects(cell: str) -> list[str]:
    """Unlink every shm object and semaphore of ``cell``; returns what was removed."""
    removed = []
    for entry in cell_objects(cell):
        try:
            os.unlink(os.path.join(SHM_DIR, entry))
            removed.append(entry)
        except FileNotFoundError:
            pass
    return removed


class _Held:
    """``with`` the record of a :class:`MemoryDatabase`: nothing to take or release in one
    process, so one object serves every ``locked()`` (a generator context manager cost a
    microsecond a use, several times a lockstep tick; issue 44)."""

    __slots__ = ("_view",)

    def __init__(self, view: np.ndarray) -> None:
        self._view = view

    def __enter__(self) -> np.ndarray:
        return self._view

    def __exit__(self, *exc) -> bool:
        return False


class MemoryDatabase:
    """Same interface as :class:`Database`, in process memory (lockstep mode)."""

    def __init__(self, name: str, layout: Layout) -> None:
        self.name = name
        self.layout = layout
        self._view = new_record(layout)
        self._held = _Held(self._view)

    def locked(self) -> _Held:
        return self._held

    def read(self) -> np.ndarray:
        return np.ndarray((), dtype=self.layout.dtype, buffer=bytearray(self._view.tobytes()))

    def write(self, rec: np.ndarray | None = None, **fields) -> int:
        if rec is not None:
            hdr = self._view[["magic", "version", "kind", "size", "writer_pid", "holder_pid",
                              "flags", "seq"]].copy()
            self._view[...] = rec
            for k in hdr.dtype.names:
                self._view[k] = hdr[k]
        for k, val in fields.items():
            self._view[k] = val
        return self._bump()

    def update(self, **fields) -> int:
        return self.write(None, **fields)

    def _bump(self) -> int:
        seq = int(self._view["seq"]) + 1
        self._view["seq"] = seq
        return seq

    def mark_written(self) -> int:
        return self._bump()

    @property
    def seq(self) -> int:
        return int(self._view["seq"])

    def raw_bytes(self) -> bytes:
        return self._view.tobytes()

    def close(self) -> None:
        pass

    def unlink(self) -> None:
        pass
