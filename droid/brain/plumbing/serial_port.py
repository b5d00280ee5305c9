"""The cell's one serial port: open by URL, read everything waiting, write, notice when it vanishes.

docs/design.md §9: "Read with ``read(in_waiting)`` and split lines; ``readline`` makes
one syscall a byte."  :class:`PortLink` wraps a pyserial object (or anything
with ``in_waiting``, ``read``, ``write``, ``reset_input_buffer``, ``close``)
and never raises: an I/O error closes the port and is kept in ``last_error``;
a pty whose other side went away reports a hang-up, caught by a zero-timeout
poll of the port's fd where there is one.  Who reopens decides when:
:class:`ReopeningPort` retries after a back-off in heartbeat ticks (the
Brain's sensor link); the GMF1 serial core runs its own back-off in ticks
(FAULT_DEVICE meanwhile).  Users: droid-gmf1-serial (the KAREL line, thesis
§4.2.4) and droid-remote of a serial-linked sensor (§5.4).
"""
from __future__ import annotations

import select
from typing import Callable

import serial

from droid.brain.plumbing.wire import LIVENESS_TICKS, MAX_BACKOFF_TICKS
from droid.cli import BadInput

READ_ROUNDS = 64  # socket:// reports at most 1 byte in_waiting: bound the loop
_HANGUP = select.POLLHUP | select.POLLERR | select.POLLNVAL


def serial_opener(url: str, baud: int, *, write_timeout_s: float = 0.5) -> Callable[[], object]:
    """A function opening ``url`` (device path or pyserial URL) at ``baud`` (non-blocking reads,
    writes waiting at most ``write_timeout_s`` [s]); checks the URL form now."""
    try:
        probe = serial.serial_for_url(url, baudrate=baud, do_not_open=True)
    except (ValueError, serial.SerialException) as exc:
        raise BadInput(f"serial port {url!r}: {exc}") from None
    del probe

    def opener():
        return serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=write_timeout_s)

    return opener


class PortLink:
    """A port that can be open or closed; I/O errors close it (see the module docstring).

    ``bad_url``: a ValueError from the opener (pyserial: a malformed URL or
    setting) raises BadInput naming ``bad_url`` instead of counting as a
    failed open (for openers that did not check the URL beforehand)."""

    def __init__(self, opener: Callable[[], object], *, bad_url: str | None = None,
                 write_timeout_keeps_open: bool = False) -> None:
        self._opener = opener
        self._bad_url = bad_url
        # a write that timed out (the line is slower than the writer): an error that
        # closes the port (default), or counted in write_timeouts with the port kept
        self.write_timeout_keeps_open = write_timeout_keeps_open
        self.write_timeouts = 0
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
        except ValueError as exc:
            if self._bad_url is not None:
                raise BadInput(f"serial {self._bad_url}: {exc}") from None
            self.last_error = str(exc) or type(exc).__name__
            return False
        except (serial.SerialException, OSError) as exc:
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

    def read(self, max_bytes: int | None = None) -> bytes:
        """Everything waiting, up to ``max_bytes`` (b"" if nothing, or if the port failed and was closed)."""
        if self.port is None:
            return b""
        chunks = []
        left = max_bytes
        try:
            for _ in range(READ_ROUNDS):
                n = self.port.in_waiting
                if left is not None:
                    n = min(n, left)
                if not n:
                    break
                data = self.port.read(n)
                if left is not None:
                    left -= len(data)
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
        """Write ``data``; False if the port is closed, the write timed out or failed (closing it)."""
        if self.port is None:
            return False
        try:
            self.port.write(data)
            return True
        except serial.SerialTimeoutException as exc:
            if not self.write_timeout_keeps_open:
                self._fail(exc)
            else:
                self.write_timeouts += 1
            return False
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


class ReopeningPort:
    """A :class:`PortLink` polled once a tick and reopened with back-off in ticks.

    :meth:`poll` returns ``(bytes, port_ok)`` and never blocks.  A port that
    cannot be opened, or fails while reading (EIO, hang-up), is closed and
    tried again after ``min_backoff_ticks`` ticks, the wait doubling up to
    ``max_backoff_ticks``; a good read resets it.  ``opener(url, baud)``
    opens the port (default: pyserial's ``serial_for_url``, non-blocking); a
    URL it rejects as malformed is a :class:`BadInput`.
    """

    def __init__(self, url: str, baud: int, *, min_backoff_ticks: int = LIVENESS_TICKS,
                 max_backoff_ticks: int = MAX_BACKOFF_TICKS,
                 max_read_bytes: int | None = None, opener=None) -> None:
        self.url = url
        self.baud = baud
        self.min_backoff = max(1, min_backoff_ticks)
        self.max_backoff = max(self.min_backoff, max_backoff_ticks)
        self.max_read_bytes = max_read_bytes
        self.opener = opener or _nonblocking_opener
        self.link = PortLink(lambda: self.opener(self.url, self.baud), bad_url=url)
        self._backoff = self.min_backoff
        self._wait = 0
        self.failures = 0  # failed opens and lost ports

    # the link's state, read-only
    port = property(lambda self: self.link.port, doc="The open port, None while closed.")
    opens = property(lambda self: self.link.opens, doc="How many times the port was opened.")
    last_error = property(lambda self: self.link.last_error, doc="Why the port last failed or did not open.")

    def _fail(self) -> None:
        self.failures += 1
        self._wait = self._backoff
        self._backoff = min(self._backoff * 2, self.max_backoff)

    def start(self) -> bool:
        """Try to open the port now (a malformed URL raises BadInput); True if open."""
        if self.link.is_open:
            return True
        if self.link.open():
            return True
        self._fail()
        return False

    def poll(self) -> tuple[bytes, bool]:
        """This tick's bytes and whether the port is open (never blocks)."""
        if not self.link.is_open:
            if self._wait > 0:
                self._wait -= 1
                return b"", False
            if not self.start():
                return b"", False
        data = self.link.read(self.max_read_bytes)
        if not self.link.is_open:
            self._fail()
            return b"", False
        self._backoff = self.min_backoff
        return data, True

    def close(self) -> None:
        self.link.close()


def _nonblocking_opener(url: str, baud: int):
    return serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0)
