"""DSP board drivers: how droid-mvs reads stripe frames (thesis §5.4, power2()).

sensor.exe's power2() waits for the board's vertical retrace and copies the
240 stripe columns out within about 1 ms, before the board refreshes them.
A driver here does the same through :meth:`DspBoard.wait_frame`.  The board
is chosen by URL (as pyserial chooses a port):

``shm://NAME``
    A POSIX shared-memory frame buffer ``/NAME`` (layout ``wire.DSP_RECORD``:
    header with a seqlock sequence and a frame counter, then 240 int16
    columns) and a named POSIX semaphore ``/NAME.retrace`` posted at each
    vertical retrace.  The board (droid-sim's DSP twin) creates both; this
    reader only opens them.  A torn copy (the writer was mid-frame) is retried.
    One reader per board: the retrace semaphore is an event for one consumer.
    Example: ``shm://droid.sim.mvs.dsp``.

``inproc://NAME``
    A channel inside one process (the lockstep runner, tests); the writer
    publishes into :func:`inproc_channel` ``(NAME)``.  No options.
"""
from __future__ import annotations

import mmap
import os
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import posix_ipc

from droid.cli import RuntimeFailure
from droid.subunits.regmap import parse_url
from droid.subunits.mvs.wire import (COLUMNS, DSP_LAYOUT_VERSION, DSP_MAGIC, DSP_RECORD,
                                     RETRACE_SUFFIX, ROWS)

URL_FORMS = "shm://NAME or inproc://NAME"
#: Attempts at an untorn copy of one frame.
COPY_RETRIES = 100
#: Poll period while waiting for a board to appear [s].
APPEAR_POLL_S = 0.02


@dataclass(frozen=True)
class DspFrame:
    """One frame copied off the board."""

    frame: int  # the board's frame counter (frames written since it started)
    rows: np.ndarray  # int16 (240,) stripe columns, -1 = no stripe (a private copy)
    missed: int  # frames the board wrote since the previous read (or the opening) that were skipped


def parse_dsp_url(url: str) -> tuple[str, str]:
    """(scheme, NAME) of a DSP URL; BadInput names the expected form (droid.subunits.regmap's checks)."""
    scheme, name, _ = parse_url(url, "DSP", ("shm", "inproc"), URL_FORMS)
    return scheme, name


class DspBoard(ABC):
    """A frame source: wait for the retrace, copy the rows."""

    def __init__(self, url: str):
        self.url = url
        self._last = 0  # frame counter of the last frame read (or at opening)

    def _frame(self, counter: int, rows: np.ndarray) -> DspFrame:
        missed = max(0, counter - self._last - 1)
        self._last = counter
        return DspFrame(counter, rows, missed)

    @abstractmethod
    def wait_frame(self, timeout_s: float) -> DspFrame | None:
        """Wait up to ``timeout_s`` [s] for the next retrace; the frame, or None on timeout."""

    @abstractmethod
    def close(self) -> None:
        """Release the board."""

    def __enter__(self) -> "DspBoard":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class _ShmAttachment:
    """One mapping of a board: the record, its semaphore, and the object's identity."""

    map: mmap.mmap
    rec: np.ndarray
    sem: posix_ipc.Semaphore
    inode: int

    def close(self) -> None:
        self.rec = None
        self.map.close()
        self.sem.close()


def _shm_inode(name: str) -> int | None:
    """Identity of the shared-memory object /name now (None if absent)."""
    try:
        shm = posix_ipc.SharedMemory("/" + name)
    except posix_ipc.ExistentialError:
        return None
    try:
        return os.fstat(shm.fd).st_ino
    finally:
        shm.close_fd()


def _attach(url: str, name: str) -> _ShmAttachment:
    """Map the board /name and open its retrace semaphore; RuntimeFailure if it is not a board."""
    try:
        shm = posix_ipc.SharedMemory("/" + name)
    except posix_ipc.ExistentialError:
        raise RuntimeFailure(f"DSP board {url}: not present (no shared memory /{name})") from None
    try:
        if shm.size < DSP_RECORD.itemsize:
            raise RuntimeFailure(f"DSP board {url}: /{name} is {shm.size} bytes, "
                                 f"an MVS frame buffer needs {DSP_RECORD.itemsize}")
        inode = os.fstat(shm.fd).st_ino
        mapping = mmap.mmap(shm.fd, DSP_RECORD.itemsize)
    finally:
        shm.close_fd()
    rec = np.ndarray((), DSP_RECORD, buffer=mapping)
    header = (int(rec["magic"]), int(rec["version"]), int(rec["rows"]), int(rec["columns"]))
    if header != (DSP_MAGIC, DSP_LAYOUT_VERSION, ROWS, COLUMNS):
        del rec
        mapping.close()
        raise RuntimeFailure(f"DSP board {url}: /{name} is not an MVS frame buffer "
                             f"(magic/version/rows/columns {header})")
    try:
        sem = posix_ipc.Semaphore("/" + name + RETRACE_SUFFIX)
    except posix_ipc.ExistentialError:
        del rec
        mapping.close()
        raise RuntimeFailure(f"DSP board {url}: no retrace semaphore /{name}{RETRACE_SUFFIX}") from None
    return _ShmAttachment(mapping, rec, sem, inode)


class ShmDspBoard(DspBoard):
    """Reader of a shared-memory DSP board (see the module docstring).

    When a wait times out and the board has been recreated meanwhile (droid-sim
    restarted), the reader attaches to the new one.
    """

    def __init__(self, url: str, name: str):
        super().__init__(url)
        self.name = name
        self._board: _ShmAttachment | None = _attach(url, name)
        self._last = int(self._board.rec["frames"])

    @property
    def writer_pid(self) -> int:
        """PID of the process that created the board."""
        return int(self._board.rec["writer_pid"])

    def _reattach_if_replaced(self) -> None:
        inode = _shm_inode(self.name)
        if inode is None or inode == self._board.inode:
            return
        try:
            fresh = _attach(self.url, self.name)
        except RuntimeFailure:
            return  # being created: try again at the next timeout
        self._board.close()
        self._board = fresh
        self._last = 0

    def _copy(self) -> tuple[int, np.ndarray] | None:
        rec = self._board.rec
        for _ in range(COPY_RETRIES):
            before = int(rec["sequence"])
            if before & 1:
                continue
            rows = rec["stripe"].copy()
            counter = int(rec["frames"])
            if int(rec["sequence"]) == before:
                return counter, rows
        return None

    def wait_frame(self, timeout_s: float) -> DspFrame | None:
        sem = self._board.sem
        try:
            sem.acquire(max(0.0, timeout_s))
        except posix_ipc.SignalError:
            return None
        except posix_ipc.BusyError:
            self._reattach_if_replaced()
            return None
        while True:  # swallow retraces we were too slow for; the counter says how many
            try:
                sem.acquire(0)
            except (posix_ipc.BusyError, posix_ipc.SignalError):
                break
        copied = self._copy()
        if copied is None:
            return None
        return self._frame(*copied)

    def close(self) -> None:
        if self._board is not None:
            self._board.close()
            self._board = None


class InprocChannel:
    """A DSP board inside one process: the writer publishes, one reader waits."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.frames = 0
        self._rows = np.full(ROWS, -1, np.int16)

    def publish(self, rows: np.ndarray) -> int:
        """Store a frame and signal the retrace; returns the new frame counter."""
        with self._cond:
            self._rows = np.array(rows, dtype=np.int16, copy=True)
            self.frames += 1
            self._cond.notify_all()
            return self.frames

    def _latest_after(self, last: int, timeout_s: float) -> tuple[int, np.ndarray] | None:
        with self._cond:
            if not self._cond.wait_for(lambda: self.frames > last, timeout=max(0.0, timeout_s)):
                return None
            return self.frames, self._rows.copy()


_INPROC: dict[str, InprocChannel] = {}
_INPROC_LOCK = threading.Lock()


def inproc_channel(name: str) -> InprocChannel:
    """The in-process channel NAME (created on first use)."""
    with _INPROC_LOCK:
        return _INPROC.setdefault(name, InprocChannel())


def forget_inproc_channel(name: str) -> None:
    """Drop the channel NAME from the registry (the writer closes the board)."""
    with _INPROC_LOCK:
        _INPROC.pop(name, None)


class InprocDspBoard(DspBoard):
    """Reader of an :class:`InprocChannel`."""

    def __init__(self, url: str, name: str):
        super().__init__(url)
        self._channel = inproc_channel(name)
        self._last = self._channel.frames

    def wait_frame(self, timeout_s: float) -> DspFrame | None:
        got = self._channel._latest_after(self._last, timeout_s)
        return None if got is None else self._frame(*got)

    def close(self) -> None:
        pass


def open_dsp(url: str, wait_s: float = 0.0) -> DspBoard:
    """Open the DSP board at ``url``; wait up to ``wait_s`` [s] for it to appear."""
    scheme, name = parse_dsp_url(url)
    if scheme == "inproc":
        return InprocDspBoard(url, name)
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return ShmDspBoard(url, name)
        except RuntimeFailure:
            if time.monotonic() >= deadline:
                raise
            time.sleep(APPEAR_POLL_S)
