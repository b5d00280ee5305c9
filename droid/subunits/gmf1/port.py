"""The serial program's port: open by URL, read everything waiting, write, notice when it vanishes.

DESIGN §9: "Read with ``read(in_waiting)`` and split lines; ``readline`` makes
one syscall a byte."  :class:`PortLink` wraps a pyserial object (or anything
with ``in_waiting``, ``read``, ``write``, ``reset_input_buffer``, ``close``)
and never raises: an I/O error closes the port and is kept in ``last_error``;
the serial core sees a closed port (FAULT_DEVICE) and asks for a reopen with
back-off.  A pty whose other side went away reports a hang-up, caught by a
zero-timeout poll of the port's fd where there is one.
"""
from __future__ import annotations

import select
from typing import Callable

import serial

from droid.cli import BadInput

READ_ROUNDS = 64  # socket:// reports at most 1 byte in_waiting: bound the loop
_HANGUP = select.POLLHUP | select.POLLERR | select.POLLNVAL


def serial_opener(url: str, baud: int) -> Callable[[], object]:
    """A function opening ``url`` (device path or pyserial URL) at ``baud``; checks the URL form now."""
    try:
        probe = serial.serial_for_url(url, baudrate=baud, do_not_open=True)
    except (ValueError, serial.SerialException) as exc:
        raise BadInput(f"serial port {url!r}: {exc}") from None
    del probe

    def opener():
        return serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0.5)

    return opener


class PortLink:
    """A port that can be open or closed; I/O errors close it (see the module docstring)."""

    def __init__(self, opener: Callable[[], object]) -> None:
        self._opener = opener
        self.port = None
        self.last_error = ""
        self.opens = 0
        self.errors = 0
        self._poll = None

    @property
    def is_open(self) -> bool:
        return self.port is not None

    def open(self) -> bool:
        """Try to open; True on success (input left over from before is discarded)."""
        if self.port is not None:
            return True
        try:
            port = self._opener()
            port.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            self.last_error = str(exc) or type(exc).__name__
            return False
        self.port = port
        self.opens += 1
        self._poll = None
        fileno = getattr(port, "fileno", None)
        if fileno is not None:
            try:
                fd = fileno()
                self._poll = select.poll()
                self._poll.register(fd, select.POLLIN | select.POLLPRI)
            except (OSError, ValueError, AttributeError, TypeError, serial.SerialException):
                self._poll = None
        return True

    def _fail(self, exc: BaseException) -> None:
        self.errors += 1
        self.last_error = str(exc) or type(exc).__name__
        self.close()

    def read(self) -> bytes:
        """Everything waiting (b"" if nothing, or if the port failed and was closed)."""
        if self.port is None:
            return b""
        chunks = []
        try:
            for _ in range(READ_ROUNDS):
                n = self.port.in_waiting
                if not n:
                    break
                data = self.port.read(n)
                if not data:
                    break
                chunks.append(data)
            if not chunks and self._poll is not None:
                for _fd, ev in self._poll.poll(0):
                    if ev & _HANGUP:
                        raise serial.SerialException("the device hung up")
        except (serial.SerialException, OSError, ValueError) as exc:
            self._fail(exc)
            return b"".join(chunks)
        return b"".join(chunks)

    def write(self, data: bytes) -> bool:
        if self.port is None:
            return False
        try:
            self.port.write(data)
            return True
        except (serial.SerialException, OSError, ValueError) as exc:
            self._fail(exc)
            return False

    def close(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except Exception:  # a port that fails to close is closed for us anyway
                pass
            self.port = None
            self._poll = None
