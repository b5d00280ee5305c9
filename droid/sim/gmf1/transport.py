"""Where the simulated controller's serial port appears to DROID programs.

* :class:`PtyTransport` — a pseudo-terminal; the slave's path is published by
  a symlink (e.g. ``{run}/gmf1.tty``) that programs open with
  ``serial.serial_for_url(path)`` as they would open ``/dev/ttyS0``;
* :class:`TcpTransport` — ``socket://HOST:PORT``: the controller listens, one
  client at a time (pyserial's ``socket://`` handler connects);
* :class:`MemorySerialPair` — the in-process pair of the lockstep mode: a
  device end and a host end with the pyserial calls DROID uses.

A pty or a socket does not enforce baud: the controller paces its own bytes
(:mod:`droid.sim.gmf1.pacing`).  Device ends are non-blocking; bytes the host
is not there to take are dropped and counted, as on a real line.
"""
from __future__ import annotations

import errno
import os
import socket
import tty
from pathlib import Path

import serial

READ_CHUNK = 4096


class PtyTransport:
    """The master side of a pty; the slave path is published at ``link_path`` (atomically replaced)."""

    def __init__(self, link_path: str) -> None:
        self.link_path = str(link_path)
        self.master, self._slave = os.openpty()
        try:
            tty.setraw(self._slave)  # no echo, no CR/LF translation until a program configures it
            os.set_blocking(self.master, False)
            self.slave_path = os.ttyname(self._slave)
            Path(self.link_path).parent.mkdir(parents=True, exist_ok=True)
            tmp = f"{self.link_path}.{os.getpid()}.tmp"
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            os.symlink(self.slave_path, tmp)
            os.replace(tmp, self.link_path)
        except BaseException:
            os.close(self.master)
            os.close(self._slave)
            raise
        self.dropped = 0

    def read_available(self) -> bytes:
        """Everything the program wrote since the last call (b"" if nothing)."""
        chunks = []
        while True:
            try:
                data = os.read(self.master, READ_CHUNK)
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno == errno.EIO:  # no slave open (cannot happen while we hold one)
                    break
                raise
            if not data:
                break
            chunks.append(data)
            if len(data) < READ_CHUNK:
                break
        return b"".join(chunks)

    def write(self, data: bytes) -> None:
        try:
            n = os.write(self.master, data)
        except BlockingIOError:
            n = 0
        self.dropped += len(data) - n

    def close(self) -> None:
        try:
            if os.readlink(self.link_path) == self.slave_path:
                os.unlink(self.link_path)
        except OSError:
            pass
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
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


class TcpTransport:
    """A listening TCP socket for ``socket://HOST:PORT``; the newest client is the one served."""

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
                data = self._client.recv(READ_CHUNK)
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

    def write(self, data: bytes) -> None:
        if self._client is None:
            self.dropped += len(data)
            return
        try:
            n = self._client.send(data)
        except BlockingIOError:
            n = 0
        except OSError:
            self._client.close()
            self._client = None
            n = 0
        self.dropped += len(data) - n

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._listen.close()


class MemorySerialPair:
    """An in-process serial line for lockstep: ``device`` end (transport) and ``host`` end (pyserial-like).

    :meth:`vanish` makes the host end fail like a port whose device went away;
    :meth:`restore` brings the line back (a later open succeeds).
    """

    def __init__(self) -> None:
        self._to_host = bytearray()
        self._to_device = bytearray()
        self.present = True
        self.device = _DeviceEnd(self)

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


class _DeviceEnd:
    def __init__(self, pair: MemorySerialPair) -> None:
        self._pair = pair
        self.dropped = 0

    def read_available(self) -> bytes:
        if not self._pair._to_device:
            return b""
        data = bytes(self._pair._to_device)
        self._pair._to_device.clear()
        return data

    def write(self, data: bytes) -> None:
        if self._pair.present:
            self._pair._to_host += data
        else:
            self.dropped += len(data)

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
