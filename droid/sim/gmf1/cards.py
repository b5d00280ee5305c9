"""The card side of the two CIO-QUAD04-like encoder cards (thesis §2.4, §4.2.5): counting hardware.

:class:`Quad04Twin` writes the registers of :mod:`droid.subunits.gmf1.quad04_map`
into two buffers (shared memory under droid-sim, bytearrays in lockstep):

* each joint's motor encoder position [counts, from the controller's joint
  angles through the robot's gearing] plus the channel's power-up value,
  modulo 2**24, into COUNT — counters hold arbitrary values at power-up
  (seeded), exactly why the encoder program must home;
* LATCH / RESET commands written into CTRL are executed on the next update:
  LATCH copies COUNT, RESET makes the counter read 0 at the current position;
  then CTRL is cleared and DONE incremented.

One update reads each card's 64-byte channel block once and writes only the
words that changed, so stepping it at the world rate costs a few microseconds.
"""
from __future__ import annotations

import mmap

import numpy as np
import posix_ipc

from droid.subunits.gmf1 import quad04_map as qm

_SLOTS = qm.CARDS * qm.CHANNELS


class Quad04Twin:
    """Two cards' registers driven by six motor positions; see the module docstring."""

    def __init__(self, bufs, rng: np.random.Generator) -> None:
        if len(bufs) != qm.CARDS:
            raise ValueError(f"need {qm.CARDS} card buffers")
        self._mvs = []
        for b in bufs:
            mv = memoryview(b)
            if mv.nbytes < qm.MAP_SIZE:
                raise ValueError("card buffer too small")
            mv[: qm.MAP_SIZE] = bytes(qm.MAP_SIZE)
            qm.format_header(mv)
            self._mvs.append(mv)
        self._words = [qm.words(mv) for mv in self._mvs]  # single stores (qm.words: no torn 0)
        self.offset = [int(v) for v in rng.integers(0, 1 << qm.COUNTER_BITS, size=_SLOTS)]
        self._motor = [0] * _SLOTS  # whole motor counts of each slot (unused channels stay 0)
        self._written = [-1] * _SLOTS
        self.commands_done = 0

    def update(self, motor_counts=None) -> None:
        """Set the motor positions [counts, 6 values] (None: unchanged) and execute pending commands."""
        if motor_counts is not None:
            for j in range(qm.JOINTS):
                self._motor[j] = int(round(float(motor_counts[j])))
        for card in range(qm.CARDS):
            mv, words = self._mvs[card], self._words[card]
            w = qm.CHANNEL_BLOCK.unpack_from(mv, qm.OFF_CHANNEL0)
            if motor_counts is None and not (w[2] or w[6] or w[10] or w[14]):
                continue  # nothing moved, no command: the registers are up to date
            for ch in range(qm.CHANNELS):
                slot = card * qm.CHANNELS + ch
                count = (self._motor[slot] + self.offset[slot]) & qm.COUNTER_MASK
                cmd = w[4 * ch + 2]
                base = (qm.OFF_CHANNEL0 + qm.CHANNEL_STRIDE * ch) // 4  # the channel's first word
                if cmd:
                    if cmd == qm.CMD_RESET:
                        self.offset[slot] = -self._motor[slot]
                        count = 0
                    elif cmd == qm.CMD_LATCH:
                        words[base + qm.REG_LATCH // 4] = count
                    words[base + qm.REG_CTRL // 4] = qm.CMD_NONE
                    words[base + qm.REG_DONE // 4] = (w[4 * ch + 3] + 1) & 0xFFFFFFFF
                    self.commands_done += 1
                if count != self._written[slot]:
                    words[base + qm.REG_COUNT // 4] = count
                    self._written[slot] = count

    def power(self, on: bool) -> None:
        """Set or clear the cards' POWER status bit (the encoder program reports an unpowered card)."""
        for words in self._words:
            st = words[qm.OFF_STATUS // 4]
            words[qm.OFF_STATUS // 4] = (st | qm.STATUS_POWER) if on else (st & ~qm.STATUS_POWER)

    def release(self) -> None:
        """Drop the views on the buffers (before a shared map is closed)."""
        for v in self._words + self._mvs:
            v.release()
        self._mvs, self._words = [], []


class SharedCard:
    """One card's register map as a POSIX shared-memory object ``/NAME`` (created, unlinked on close)."""

    def __init__(self, name: str) -> None:
        self.name = name
        try:
            posix_ipc.unlink_shared_memory("/" + name)  # a stale map of a crashed world
        except posix_ipc.ExistentialError:
            pass
        shm = posix_ipc.SharedMemory("/" + name, posix_ipc.O_CREX, mode=0o600, size=qm.MAP_SIZE)
        try:
            self.buf = mmap.mmap(shm.fd, qm.MAP_SIZE)
        except BaseException:
            shm.close_fd()
            shm.unlink()
            raise
        shm.close_fd()

    @property
    def url(self) -> str:
        return f"shm://{self.name}"

    def close(self) -> None:
        if self.buf is not None:
            self.buf.close()
            self.buf = None
            try:
                posix_ipc.unlink_shared_memory("/" + self.name)
            except posix_ipc.ExistentialError:
                pass
