"""What every serial line shares: the byte time on the wire and the line splitter.

Both serial protocols of the cell are ASCII lines: the KAREL server's
requests and replies on the Fanuc's port (thesis §4.2.4,
:mod:`droid.subunits.gmf1.karel_wire`) and the sensors' ``x,y,roll`` lines
to the Brain (§5.4, :mod:`droid.brain.plumbing.sensor_line`).  docs/design.md §9: read with
``read(in_waiting)`` and split lines yourself -- this module's
:class:`LineSplitter` is that one splitter, with the two protocols' policies
as options.  Pure: no I/O, no clock.
"""
from __future__ import annotations

import re

#: Bits on the wire per byte (8N1: start + 8 data + stop).
BITS_PER_BYTE = 10


class LineSplitter:
    """Accumulates serial chunks and returns complete lines (without their terminator).

    ``ends``: the bytes that end a line (``b"\\n"``; ``b"\\r\\n"``: either ends one).
    ``skip_empty``: drop empty lines (a CR LF pair read as two ends gives one).
    The buffer is bounded: of a line longer than ``max_line_bytes`` only the
    first ``max_line_bytes + 1`` bytes are kept and returned (so the parser
    rejects it), and ``overlong`` counts it; with ``early_overlong`` that
    happens as soon as the unfinished line is too long, and the rest of it,
    up to its end, is dropped.

    :meth:`resync` drops the unfinished line and skips to the next line end
    (a port just reopened may start mid-line); ``skipped`` counts the bytes.
    """

    def __init__(self, max_line_bytes: int, ends: bytes = b"\n", *, skip_empty: bool = False,
                 early_overlong: bool = False) -> None:
        if not ends:
            raise ValueError("LineSplitter: ends must name at least one byte")
        self.max_line_bytes = max_line_bytes
        self.ends = bytes(ends)
        self.skip_empty = skip_empty
        self.early_overlong = early_overlong
        self.overlong = 0
        self.skipped = 0
        self._split = (lambda b: b.split(self.ends)) if len(self.ends) == 1 else \
            re.compile(b"[" + re.escape(self.ends) + b"]").split
        self._buffer = bytearray()
        self._discarding = False  # early_overlong: inside the rest of an overlong line
        self._resync = False

    def _add(self, piece: bytes) -> None:
        room = self.max_line_bytes + 1 - len(self._buffer)
        if room > 0:
            self._buffer += piece[:room]

    def _first_end(self, chunk: bytes) -> int:
        found = [i for i in (chunk.find(bytes([e])) for e in self.ends) if i >= 0]
        return min(found) if found else -1

    def feed(self, chunk: bytes) -> list[bytes]:
        """Add a chunk; return the lines it completed, oldest first."""
        chunk = bytes(chunk)
        if not chunk:
            return []
        if self._resync:
            end = self._first_end(chunk)
            if end < 0:
                self.skipped += len(chunk)
                return []
            self.skipped += end + 1
            chunk = chunk[end + 1:]
            self._resync = False
        *complete, tail = self._split(chunk)
        lines = []
        for piece in complete:
            if self._discarding:  # the end of an overlong line already returned
                self._discarding = False
                self._buffer.clear()
                continue
            self._add(piece)
            line = bytes(self._buffer)
            self._buffer.clear()
            if len(line) > self.max_line_bytes:
                self.overlong += 1
            if line or not self.skip_empty:
                lines.append(line)
        if self._discarding:
            return lines
        self._add(tail)
        if self.early_overlong and len(self._buffer) > self.max_line_bytes:
            self.overlong += 1
            lines.append(bytes(self._buffer))
            self._buffer.clear()
            self._discarding = True
        return lines

    def resync(self) -> None:
        """Drop the unfinished line and skip up to the next line end (counted in ``skipped``)."""
        self.skipped += len(self._buffer)
        self._buffer.clear()
        self._discarding = False
        self._resync = True

    def clear(self) -> None:
        """Forget the unfinished line."""
        self._buffer.clear()
        self._discarding = False
        self._resync = False

    @property
    def pending(self) -> int:
        """Bytes of the unfinished line."""
        return len(self._buffer)
