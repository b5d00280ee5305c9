"""Simulated serial lines: a cable between two pseudo-terminals, paced at its baud rate.

The MVS PC writes its "x,y,roll" lines over a serial cable straight to the
Brain (thesis §2.5, §5.4); the tool-tip measuring sensor (§6.1) reports the
same way.  A pty carries bytes as fast as they are written (DESIGN §9: "a pty
or loop:// does not enforce baud"), so the world paces them itself: 10 bits a
byte (8N1) against the world's time in ``advance(dt)``.

Device type ``serial_cable`` (``[world.devices.NAME]``)::

    type = "serial_cable"
    ends = ["{run}/mvs.sensor.tty", "{run}/mvs.brain.tty"]   # end A, end B
    baud = 19200            # bit/s (default 19200)
    duplex = false          # false: A -> B only (B's input is read and discarded)

Each end is a pseudo-terminal whose slave is published as a symlink at the
path; the programs open the path like any serial device
(``serial.serial_for_url(path)``).  The world keeps its own descriptor on
each slave, so a program may close and reopen its end without the pty
hanging up; both slaves are in raw mode (no echo, no CR/LF translation).
Bytes written at A come out at B byte for byte, at most baud/10 bytes per
second of world time.  The transmitter holds :data:`UART_FIFO_BYTES`; the
world reads a writer's bytes only as they fit, so a writer faster than the
line backs up into the pty's own buffer (~20 KB) and finally blocks, as a
UART writer would.  Bytes the receiving pty cannot take (nobody read end B
for ~20 KB) are lost and counted.  Symlinks and ptys go away on close.

:class:`BytePacer` is the transmitter as a core; :class:`PacedPipe` is the
same line in memory on virtual nanoseconds, for lockstep runs.
"""
from __future__ import annotations

import errno
import os
import tty
from typing import Any

from droid.brain.sensor_line import DEFAULT_BAUD
from droid.brain.serial_line import BITS_PER_BYTE
from droid.cli import BadInput
from droid.sim.world import Device

#: Bytes a transmitter holds before the writer has to wait (a 16550's FIFO is 16;
#: a little more keeps a 200 Hz world's steps from starving the line).
UART_FIFO_BYTES = 64
#: Bytes a lockstep pipe or a device's serial output holds: a write that does not
#: fit is dropped whole (as droid-mvs drops a line that cannot go within a frame).
OUTPUT_BUFFER_BYTES = 256
#: Most bytes moved from a pty in one read.
READ_CHUNK_BYTES = 4096


class BytePacer:
    """A UART transmitter as a core: bytes in, released at baud/10 bytes a second of time.

    ``push`` queues bytes (up to ``capacity_bytes``); ``advance(dt_s)`` returns
    the bytes put on the line during that time.  Credit accrues only while
    bytes are waiting, so over any span of time T at most
    ``T * baud / 10 + 1`` bytes come out.
    """

    def __init__(self, baud: int = DEFAULT_BAUD, capacity_bytes: int = UART_FIFO_BYTES) -> None:
        if not (isinstance(baud, int) and baud > 0):
            raise ValueError(f"baud must be a positive integer, got {baud!r}")
        self.baud = baud
        self.bytes_per_s = baud / BITS_PER_BYTE
        self.capacity_bytes = capacity_bytes
        self._queue = bytearray()
        self._credit = 0.0
        self.sent = 0  # bytes put on the line so far

    @property
    def room(self) -> int:
        """Bytes that can be queued now."""
        return max(0, self.capacity_bytes - len(self._queue))

    @property
    def queued(self) -> int:
        return len(self._queue)

    def push(self, data: bytes) -> int:
        """Queue as much of ``data`` as fits; returns how many bytes were taken."""
        n = min(len(data), self.room)
        self._queue += data[:n]
        return n

    def advance(self, dt_s: float) -> bytes:
        """The bytes transmitted during the next ``dt_s`` seconds."""
        if not self._queue:
            self._credit = 0.0
            return b""
        self._credit += max(0.0, dt_s) * self.bytes_per_s
        n = min(int(self._credit), len(self._queue))
        out = bytes(self._queue[:n])
        del self._queue[:n]
        self._credit -= n
        if not self._queue:
            self._credit = 0.0  # an idle line saves no time for later
        self.sent += n
        return out


class PacedPipe:
    """A serial line in memory on virtual time [ns] (lockstep): write at one end, read at the other.

    ``write(data, t_ns)`` queues a whole write or, when it does not fit in
    ``capacity_bytes``, drops it (counted in ``dropped_writes``);
    ``read(t_ns)`` returns what has arrived by ``t_ns``.  Times must not go back.
    """

    def __init__(self, baud: int = DEFAULT_BAUD, capacity_bytes: int = OUTPUT_BUFFER_BYTES) -> None:
        self.pacer = BytePacer(baud, capacity_bytes)
        self.t_ns = 0
        self._arrived = bytearray()
        self.dropped_writes = 0

    def _advance_to(self, t_ns: int) -> None:
        if t_ns > self.t_ns:
            self._arrived += self.pacer.advance((t_ns - self.t_ns) / 1e9)
            self.t_ns = t_ns

    def write(self, data: bytes, t_ns: int) -> bool:
        """Queue ``data`` at time ``t_ns``; False (and nothing queued) if it does not fit."""
        self._advance_to(t_ns)
        if len(data) > self.pacer.room:
            self.dropped_writes += 1
            return False
        self.pacer.push(data)
        return True

    def read(self, t_ns: int) -> bytes:
        """Everything that has arrived by ``t_ns`` and was not read yet."""
        self._advance_to(t_ns)
        out = bytes(self._arrived)
        self._arrived.clear()
        return out


class PtyEnd:
    """One end of a simulated line: a pty whose slave is published as a symlink at ``path``.

    :meth:`read` returns what the program at the end wrote; :meth:`write`
    delivers bytes to it.  Neither blocks.
    """

    def __init__(self, path: str) -> None:
        self.path = os.path.abspath(path)
        if os.path.lexists(self.path) and not os.path.islink(self.path):
            raise BadInput(f"serial end {self.path}: exists and is not a symlink (will not replace it)")
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        self.master, self._slave = os.openpty()
        try:
            tty.setraw(self._slave)  # no echo, no CR/LF translation, 8 bits
            os.set_blocking(self.master, False)
            self.tty_name = os.ttyname(self._slave)
            tmp = f"{self.path}.{os.getpid()}.tmp"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.tty_name, tmp)
            os.replace(tmp, self.path)  # replaces a symlink left by a dead world
        except BaseException:
            os.close(self.master)
            os.close(self._slave)
            raise

    def read(self, max_bytes: int = READ_CHUNK_BYTES) -> bytes:
        """Bytes the program wrote into this end (up to ``max_bytes``), never blocking."""
        if max_bytes <= 0:
            return b""
        try:
            return os.read(self.master, max_bytes)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                return b""
            raise

    def write(self, data: bytes) -> int:
        """Deliver bytes to the program; returns how many the pty took (the rest is lost)."""
        if not data:
            return 0
        try:
            return os.write(self.master, data)
        except BlockingIOError:
            return 0

    def close(self) -> None:
        if self.master < 0:
            return
        try:
            if os.path.islink(self.path) and os.readlink(self.path) == self.tty_name:
                os.unlink(self.path)
        except OSError:
            pass
        os.close(self.master)
        os.close(self._slave)
        self.master = self._slave = -1


class PacedPtyOutput:
    """A device's serial output: whole writes queued, paced at ``baud``, delivered at a pty end.

    Used by devices that *are* the serial sender (the tool-tip measuring
    sensor): ``write(line)`` queues a line or drops it whole when the
    transmitter is full; ``advance(dt_s)`` puts the paced bytes on the line.
    """

    def __init__(self, path: str, baud: int = DEFAULT_BAUD, capacity_bytes: int = OUTPUT_BUFFER_BYTES) -> None:
        self.pacer = BytePacer(baud, capacity_bytes)
        self.end = PtyEnd(path)
        self.dropped_writes = 0
        self.lost_bytes = 0

    def write(self, data: bytes) -> bool:
        if len(data) > self.pacer.room:
            self.dropped_writes += 1
            return False
        self.pacer.push(data)
        return True

    def advance(self, dt_s: float) -> None:
        out = self.pacer.advance(dt_s)
        if out:
            self.lost_bytes += len(out) - self.end.write(out)
        self.end.read()  # nothing is listening on this direction: keep the buffer empty

    def close(self) -> None:
        self.end.close()


class SerialCable(Device):
    """Two pty ends joined by a paced line (see the module docstring)."""

    def __init__(self, name: str, end_a: str, end_b: str, baud: int = DEFAULT_BAUD, duplex: bool = False,
                 fifo_bytes: int = UART_FIFO_BYTES) -> None:
        self.name = name
        self.baud = baud
        self.duplex = duplex
        self.a = PtyEnd(end_a)
        try:
            self.b = PtyEnd(end_b)
        except BaseException:
            self.a.close()
            raise
        self._lines = [(self.a, self.b, BytePacer(baud, fifo_bytes))]
        if duplex:
            self._lines.append((self.b, self.a, BytePacer(baud, fifo_bytes)))
        self.lost_bytes = 0  # bytes the receiving pty did not take

    @property
    def carried(self) -> list[int]:
        """Bytes carried A -> B (and B -> A when duplex)."""
        return [p.sent for _, _, p in self._lines]

    def advance(self, dt_s: float) -> None:
        for src, dst, pacer in self._lines:
            if pacer.room:
                pacer.push(src.read(pacer.room))
            out = pacer.advance(dt_s)
            if out:
                self.lost_bytes += len(out) - dst.write(out)
        if not self.duplex:
            self.b.read()  # the B side transmits into nothing

    def close(self) -> None:
        self.a.close()
        self.b.close()


def serial_cable(world, name: str, options: dict[str, Any]) -> SerialCable:
    """Factory for ``type = "serial_cable"`` (droid.sim.world.DEVICE_TYPES)."""
    from droid.sim.device_options import DeviceOptions

    opts = DeviceOptions(world, name, options)
    ends = opts.get("ends", list)
    if len(ends) != 2 or not all(isinstance(e, str) and e for e in ends):
        raise opts.bad("ends must be two paths [end A, end B]")
    if os.path.abspath(ends[0]) == os.path.abspath(ends[1]):
        raise opts.bad("the two ends must be different paths")
    baud = opts.get("baud", int, DEFAULT_BAUD, check=lambda v: None if v > 0 else "must be > 0")
    duplex = opts.get("duplex", bool, False)
    opts.done()
    return SerialCable(name, ends[0], ends[1], baud, duplex)
