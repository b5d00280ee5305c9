"""Simulated serial lines, once for every twin: the pacer, the pty end, the socket end, the in-memory pair.

The MVS PC writes its "x,y,roll" lines over a serial cable straight to the
Brain (thesis §2.5, §5.4); the tool-tip measuring sensor (§6.1) reports the
same way; the Fanuc's KAREL program talks to the GMF1 PC over RS-232 at 9600
baud (§4.2.4).  A pty or a socket carries bytes as fast as they are written
(docs/design.md §9: "a pty or loop:// does not enforce baud"), so the world paces them
itself, 10 bits a byte (8N1).  Every simulated serial line is built from the
pieces here:

* :class:`PacedLine` — the one pacer: one direction of a line at ``baud`` on
  absolute time (whole bit times, so deadlines never drift); :class:`BytePacer`
  is the same line stepped by ``advance(dt_s)`` (world devices);
* :class:`PtyEnd` — a pseudo-terminal whose slave is published as a symlink
  (programs open it with ``serial.serial_for_url(path)``); :class:`TcpEnd` —
  ``socket://HOST:PORT``, one client at a time;
* :class:`PacedPipe` — a paced line in memory on virtual nanoseconds and
  :class:`MemorySerialPair` — an unpaced device/host pair with pyserial's calls
  (lockstep runs);
* :class:`PacedPtyOutput` and the ``serial_cable`` device (below), used by
  the MVS sensor twins; the KAREL twin (:mod:`droid.sim.gmf1.karel`,
  :mod:`droid.sim.gmf1.controller`) uses :class:`PacedLine` both ways behind a
  :class:`PtyEnd` or :class:`TcpEnd`; the joystick twin writes to a
  :class:`PtyEnd`.

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
"""
from __future__ import annotations

import errno
import fcntl
import math
import os
import socket
import struct
import termios
import tty
from typing import Any

import serial

from droid.brain.plumbing.sensor_line import DEFAULT_BAUD
from droid.brain.plumbing.serial_line import BITS_PER_BYTE
from droid.cli import BadInput
from droid.sim.device import Device

#: Bytes a transmitter holds before the writer has to wait (a 16550's FIFO is 16;
#: a little more keeps a 200 Hz world's steps from starving the line).
UART_FIFO_BYTES = 64
#: Bytes a lockstep pipe or a device's serial output holds: a write that does not
#: fit is dropped whole (as droid-mvs drops a line that cannot go within a frame).
OUTPUT_BUFFER_BYTES = 256
#: Most bytes moved from a pty or a socket in one read.
READ_CHUNK_BYTES = 4096
#: Bytes a PacedLine queues unless told otherwise.
LINE_CAPACITY_BYTES = 4096

# float noise of a virtual time t_s = k * dt must not lose a bit time
_BIT_EPS = 1e-6


class PacedLine:
    """One direction of a serial line: bytes in at any speed, out at ``baud`` (8N1), on absolute time [s].

    Bytes pushed at time t cross the line one after the other; byte k of a
    burst ends its stop bit at ``start + (k + 1) * 10 / baud``, and
    :meth:`pop_due` hands out exactly the bytes whose stop bit has ended.  Time
    is kept in whole bit times (integers), so the deadlines are absolute and
    never drift, and no window of one second ever holds more than ``baud / 10``
    bytes (960 at 9600 baud) — however fast the bytes were pushed.  An idle line
    saves no time for later.  The cost is one slice per call, not a loop per byte.
    """

    def __init__(self, baud: int, capacity_bytes: int = LINE_CAPACITY_BYTES) -> None:
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

    @property
    def empty(self) -> bool:
        """Nothing queued: :meth:`pop_due` returns no bytes and changes nothing."""
        return not self._queue

    @property
    def room(self) -> int:
        """Bytes that can be queued now."""
        return max(0, self.capacity - len(self._queue))

    def push(self, data: bytes, t_s: float) -> int:
        """Bytes handed to the line at ``t_s`` [s]; returns how many were dropped (queue full)."""
        if not data:
            return 0
        if not self._queue:
            self._free_bits = max(self._free_bits, self.to_bits(t_s))
        room = self.room
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


class BytePacer(PacedLine):
    """A UART transmitter stepped by the world: :class:`PacedLine` on its own clock.

    ``push(data)`` queues as much as fits (up to ``capacity_bytes``) now and
    returns how many bytes it took; ``advance(dt_s)`` moves the clock on and
    returns the bytes put on the line meanwhile.  Over any span of time T at
    most ``T * baud / 10 + 1`` bytes come out.
    """

    def __init__(self, baud: int = DEFAULT_BAUD, capacity_bytes: int = UART_FIFO_BYTES) -> None:
        if not (isinstance(baud, int) and not isinstance(baud, bool) and baud > 0):
            raise ValueError(f"baud must be a positive integer, got {baud!r}")
        super().__init__(baud, capacity_bytes)
        self.bytes_per_s = baud / BITS_PER_BYTE
        self.capacity_bytes = capacity_bytes
        self.t_s = 0.0  # this line's clock [s]

    @property
    def sent(self) -> int:
        """Bytes put on the line so far."""
        return self.released

    def push(self, data: bytes, t_s: float | None = None) -> int:  # type: ignore[override]
        """Queue as much of ``data`` as fits; returns how many bytes were taken."""
        n = min(len(data), self.room)
        super().push(data[:n], self.t_s if t_s is None else t_s)
        return n

    def push_whole(self, data: bytes) -> bool:
        """Queue all of ``data``, or nothing (False) when it does not fit (a line dropped whole)."""
        if len(data) > self.room:
            return False
        self.push(data)
        return True

    def advance(self, dt_s: float) -> bytes:
        """The bytes transmitted during the next ``dt_s`` seconds."""
        self.t_s += max(0.0, dt_s)
        return self.pop_due(self.t_s)[0]


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
            self.pacer.t_s = t_ns / 1e9  # absolute virtual time: no sum of steps
            self._arrived += self.pacer.pop_due(self.pacer.t_s)[0]
            self.t_ns = t_ns

    def write(self, data: bytes, t_ns: int) -> bool:
        """Queue ``data`` at time ``t_ns``; False (and nothing queued) if it does not fit."""
        self._advance_to(t_ns)
        if not self.pacer.push_whole(data):
            self.dropped_writes += 1
            return False
        return True

    def read(self, t_ns: int) -> bytes:
        """Everything that has arrived by ``t_ns`` and was not read yet."""
        self._advance_to(t_ns)
        out = bytes(self._arrived)
        self._arrived.clear()
        return out


class PtyEnd:
    """One end of a simulated line: a pty whose slave is published as a symlink at ``path``.

    :meth:`read` / :meth:`read_available` return what the program at the end
    wrote; :meth:`write` delivers bytes to it (what the pty cannot take is lost
    and counted in ``dropped``).  Nothing blocks.  The world keeps its own
    descriptor on the slave, so a program may close and reopen the path; the
    slave is raw (no echo, no CR/LF translation, 8 bits) until a program
    configures it.  The symlink is replaced atomically (one left by a dead
    world is fine); a path that exists and is no symlink is refused.
    """

    def __init__(self, path: str) -> None:
        self.path = os.path.abspath(path)
        if os.path.lexists(self.path) and not os.path.islink(self.path):
            raise BadInput(f"serial end {self.path}: exists and is not a symlink (will not replace it)")
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        self.master, self._slave = os.openpty()
        try:
            tty.setraw(self._slave)
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
        self.dropped = 0

    def read(self, max_bytes: int = READ_CHUNK_BYTES) -> bytes:
        """Bytes the program wrote into this end (up to ``max_bytes``), never blocking."""
        if max_bytes <= 0:
            return b""
        # Ask first, read only what is there: the kernel's n_tty read and poll, finding no input,
        # wait for the tty buffer's flush work (a kworker of normal priority) even on a
        # non-blocking fd -- on a loaded host that held the SCHED_FIFO world for 50-335 ms at a
        # time (issue 16: "device mvs_cable took 255 ms for one 1 ms step").  FIONREAD (TIOCINQ)
        # counts what the line discipline holds without waiting; bytes still in the flip buffer
        # are read at a later step.
        try:
            waiting = struct.unpack("i", fcntl.ioctl(self.master, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:
            waiting = 0
        if waiting <= 0:
            return b""
        try:
            return os.read(self.master, min(max_bytes, waiting))
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # no slave open (cannot happen while we hold one)
                return b""
            raise

    def read_available(self) -> bytes:
        """Everything the program wrote since the last call (b"" if nothing)."""
        chunks = []
        while True:
            data = self.read(READ_CHUNK_BYTES)
            if not data:
                break
            chunks.append(data)
            if len(data) < READ_CHUNK_BYTES:
                break
        return b"".join(chunks)

    def write(self, data: bytes) -> int:
        """Deliver bytes to the program; returns how many the pty took (the rest is lost, counted)."""
        if not data:
            return 0
        try:
            n = os.write(self.master, data)
        except BlockingIOError:
            n = 0
        self.dropped += len(data) - n
        return n

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


def parse_socket_url(url: str) -> tuple[str, int]:
    """``socket://HOST:PORT`` -> (host, port); ValueError with the expected form."""
    rest = url[len("socket://"):] if url.startswith("socket://") else None
    if not rest or ":" not in rest:
        raise ValueError(f"{url!r}: expected socket://HOST:PORT")
    host, _, port = rest.rpartition(":")
    try:
        p = int(port)
    except ValueError:
        raise ValueError(f"{url!r}: port must be a number (socket://HOST:PORT)") from None
    if not 1 <= p <= 65535 or not host:
        raise ValueError(f"{url!r}: expected socket://HOST:PORT with a port in 1..65535")
    return host, p


class TcpEnd:
    """A listening TCP socket for ``socket://HOST:PORT`` (pyserial's ``socket://`` connects); the newest client is served.

    The same calls as :class:`PtyEnd` (``read_available``, ``write``,
    ``dropped``, ``close``); bytes written while no client is connected are lost.
    """

    def __init__(self, url: str) -> None:
        host, port = parse_socket_url(url)
        self.url = url
        self._listen = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self._listen.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._listen.bind((host, port))
            self._listen.listen(2)
            self._listen.setblocking(False)
        except BaseException:
            self._listen.close()
            raise
        self._client: socket.socket | None = None
        self.dropped = 0

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self._listen.accept()
            except (BlockingIOError, InterruptedError):
                return
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if self._client is not None:
                self._client.close()
            self._client = conn

    def read_available(self) -> bytes:
        self._accept()
        if self._client is None:
            return b""
        chunks = []
        while True:
            try:
                data = self._client.recv(READ_CHUNK_BYTES)
            except BlockingIOError:
                break
            except OSError:
                data = b""
            if not data:  # peer closed
                self._client.close()
                self._client = None
                break
            chunks.append(data)
        return b"".join(chunks)

    def write(self, data: bytes) -> int:
        if self._client is None:
            self.dropped += len(data)
            return 0
        try:
            n = self._client.send(data)
        except BlockingIOError:
            n = 0
        except OSError:
            self._client.close()
            self._client = None
            n = 0
        self.dropped += len(data) - n
        return n

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._listen.close()


class MemorySerialPair:
    """An in-process serial line for lockstep: ``device`` end (as :class:`PtyEnd`) and ``host`` end (pyserial-like).

    Unpaced: the device behind it paces its own bytes (:class:`PacedLine`).
    :meth:`vanish` makes the host end fail like a port whose device went away;
    :meth:`restore` brings the line back (a later open succeeds).
    """

    def __init__(self) -> None:
        self._to_host = bytearray()
        self._to_device = bytearray()
        self.present = True
        self.device = _MemoryDeviceEnd(self)

    def open_host(self) -> "MemoryHostPort":
        """What ``serial_for_url`` would return (SerialException if the line is gone)."""
        if not self.present:
            raise serial.SerialException("memory serial line: no such device")
        return MemoryHostPort(self)

    def vanish(self) -> None:
        self.present = False
        self._to_host.clear()
        self._to_device.clear()

    def restore(self) -> None:
        self.present = True


class _MemoryDeviceEnd:
    def __init__(self, pair: MemorySerialPair) -> None:
        self._pair = pair
        self.dropped = 0

    def read_available(self) -> bytes:
        if not self._pair._to_device:
            return b""
        data = bytes(self._pair._to_device)
        self._pair._to_device.clear()
        return data

    def write(self, data: bytes) -> int:
        if self._pair.present:
            self._pair._to_host += data
            return len(data)
        self.dropped += len(data)
        return 0

    def close(self) -> None:
        pass


class MemoryHostPort:
    """The host end: ``in_waiting``, ``read``, ``write``, ``reset_input_buffer``, ``close``."""

    def __init__(self, pair: MemorySerialPair) -> None:
        self._pair = pair
        self.is_open = True

    def _check(self) -> None:
        if not self.is_open:
            raise serial.PortNotOpenError()
        if not self._pair.present:
            raise serial.SerialException("memory serial line: device disappeared")

    @property
    def in_waiting(self) -> int:
        self._check()
        return len(self._pair._to_host)

    def read(self, n: int = 1) -> bytes:
        self._check()
        buf = self._pair._to_host
        data = bytes(buf[:n])
        del buf[:n]
        return data

    def write(self, data: bytes) -> int:
        self._check()
        self._pair._to_device += data
        return len(data)

    def reset_input_buffer(self) -> None:
        self._check()
        self._pair._to_host.clear()

    def close(self) -> None:
        self.is_open = False


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
        """Queue a whole line; False (counted in ``dropped_writes``) when the transmitter is full."""
        if not self.pacer.push_whole(data):
            self.dropped_writes += 1
            return False
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
    step_s = 0.004  # ~8 bytes a step at 19200 baud, within the UART FIFO it carries per step

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
