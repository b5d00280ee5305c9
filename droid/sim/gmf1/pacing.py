"""A serial line paced at its baud rate (DESIGN §9: a pty or loop:// does not enforce baud).

:class:`PacedLine` is one direction of an RS-232 line at ``baud`` with 10 bits
a byte (8N1).  Bytes pushed at time t cross the line one after the other; byte
k of a burst ends its stop bit at ``start + (k + 1) * 10 / baud``, and
:meth:`PacedLine.pop_due` hands out exactly the bytes whose stop bit has ended.
Time is kept in whole bit times (integers), so the deadlines are absolute and
never drift, and no window of one second ever holds more than ``baud / 10``
bytes (960 at 9600 baud) — however fast the bytes were pushed.

Used both ways by the simulated KAREL controller: the host's bytes arrive at
line rate, and the controller's replies leave at line rate.  The cost is one
slice per call, not a loop per byte.
"""
from __future__ import annotations

import math

from droid.subunits.gmf1.karel_wire import BITS_PER_BYTE

# float noise of a virtual time t_s = k * dt must not lose a bit time
_BIT_EPS = 1e-6


class PacedLine:
    """One direction of a serial line: bytes in at any speed, out at ``baud`` (8N1)."""

    def __init__(self, baud: int, capacity_bytes: int = 4096) -> None:
        if baud <= 0:
            raise ValueError("baud must be > 0")
        self.baud = int(baud)
        self.capacity = int(capacity_bytes)
        self._queue = bytearray()
        self._free_bits = 0  # bit time at which the line finished its last byte
        self.pushed = 0  # bytes accepted
        self.released = 0  # bytes delivered
        self.dropped = 0  # bytes lost because the queue was full

    def to_bits(self, t_s: float) -> int:
        """Whole bit times elapsed at ``t_s`` [s]."""
        return math.floor(t_s * self.baud + _BIT_EPS)

    def bits_to_s(self, bits: int) -> float:
        return bits / self.baud

    @property
    def byte_s(self) -> float:
        """Time one byte takes on the line [s]."""
        return BITS_PER_BYTE / self.baud

    def push(self, data: bytes, t_s: float) -> int:
        """Bytes handed to the line at ``t_s`` [s]; returns how many were dropped (queue full)."""
        if not data:
            return 0
        if not self._queue:
            self._free_bits = max(self._free_bits, self.to_bits(t_s))
        room = self.capacity - len(self._queue)
        lost = max(0, len(data) - room)
        if lost:
            data = data[:room]
            self.dropped += lost
        self._queue += data
        self.pushed += len(data)
        return lost

    def pop_due(self, t_s: float) -> tuple[bytes, int]:
        """(bytes whose stop bit ended by ``t_s``, bit time their first byte started)."""
        start = self._free_bits
        if not self._queue:
            return b"", start
        n = (self.to_bits(t_s) - start) // BITS_PER_BYTE
        if n <= 0:
            return b"", start
        n = min(n, len(self._queue))
        out = bytes(self._queue[:n])
        del self._queue[:n]
        self._free_bits = start + n * BITS_PER_BYTE
        self.released += n
        return out, start

    @property
    def queued(self) -> int:
        """Bytes still on their way."""
        return len(self._queue)

    def clear(self) -> None:
        self._queue.clear()
