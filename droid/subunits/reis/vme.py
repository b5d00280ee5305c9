"""VMEbus driver for the Reis interface cards (thesis §4.1.2, §4.1.5.1).

A :class:`VmeBus` reads and writes the 16-bit registers of
:mod:`droid.subunits.reis.vme_map` in any writable buffer.  Which buffer is
chosen by URL, in the style of ``serial.serial_for_url``::

    shm://NAME                 POSIX shared-memory object /NAME (the simulated
                               robot's register map, created by droid-sim)
    mem:///PATH?offset=0xADDR  mmap of a device file (/dev/mem, /dev/uioN) at
                               byte offset ADDR: the real-hardware path
    VmeBus.from_buffer(buf)    an in-process buffer (lockstep runs, tests)

Unknown schemes or options are rejected with the expected form in the
message.  The driver only moves data; it never decides (ros2_control style).
"""
from __future__ import annotations

import mmap
import os
import re
import struct
from typing import Callable, Sequence
from urllib.parse import parse_qsl, urlsplit

from droid.cli import BadInput, RuntimeFailure
from droid.subunits.reis import vme_map as vm

_ENCODERS = struct.Struct(vm.ENCODERS_FORMAT)
_DACS = struct.Struct(vm.DACS_FORMAT)
_U16 = struct.Struct(vm.U16_FORMAT)
_I16 = struct.Struct(vm.I16_FORMAT)

SHM_FORM = "shm://NAME (NAME: letters, digits, '.', '_', '-')"
MEM_FORM = "mem:///PATH?offset=0xADDR (PATH absolute, e.g. mem:///dev/uio0?offset=0x0)"
URL_FORMS = f"{SHM_FORM} or {MEM_FORM}"
_SHM_NAME = re.compile(r"^[A-Za-z0-9._-]{1,200}$")


class VmeUrlError(BadInput, ValueError):
    """A malformed or unsupported VME URL (exit code 2 in a shell)."""


class VmeOpenError(RuntimeFailure, OSError):
    """The URL is well formed but the register map cannot be opened (exit code 1)."""


class VmeBus:
    """Typed access to the Reis register map held in a writable buffer.

    ``buf`` must be writable and at least :data:`vme_map.MAP_SIZE` bytes.
    ``closer`` (optional) releases whatever backs the buffer on :meth:`close`.
    """

    def __init__(self, buf, *, closer: Callable[[], None] | None = None, url: str = "buffer:"):
        view = memoryview(buf).cast("B")
        if view.readonly:
            view.release()
            raise VmeOpenError(f"{url}: register buffer is read-only")
        if view.nbytes < vm.MAP_SIZE:
            size = view.nbytes
            view.release()
            raise VmeOpenError(f"{url}: register buffer has {size} bytes, need {vm.MAP_SIZE}")
        self._view = view
        self._closer = closer
        self.url = url
        self._kick_counter = 0

    @classmethod
    def from_buffer(cls, buf) -> "VmeBus":
        """A bus over an in-process buffer (bytearray, mmap, numpy array, ...)."""
        return cls(buf, url="buffer:")

    # -- raw registers ---------------------------------------------------
    def _check(self, offset: int) -> None:
        if offset % vm.REGISTER_BYTES or not 0 <= offset <= vm.MAP_SIZE - vm.REGISTER_BYTES:
            raise ValueError(f"register offset {offset:#x} not an aligned offset below {vm.MAP_SIZE:#x}")

    def read_u16(self, offset: int) -> int:
        """Unsigned 16-bit register at byte ``offset``."""
        self._check(offset)
        return _U16.unpack_from(self._view, offset)[0]

    def write_u16(self, offset: int, value: int) -> None:
        """Write unsigned 16-bit ``value`` (0..65535) at byte ``offset``."""
        self._check(offset)
        vm.store(self._view, offset, vm.U16_FORMAT, value)

    def read_i16(self, offset: int) -> int:
        """Signed 16-bit register at byte ``offset``."""
        self._check(offset)
        return _I16.unpack_from(self._view, offset)[0]

    def write_i16(self, offset: int, value: int) -> None:
        """Write signed 16-bit ``value`` (-32768..32767) at byte ``offset``."""
        self._check(offset)
        vm.store(self._view, offset, vm.I16_FORMAT, value)

    # -- devices ---------------------------------------------------------
    def read_encoders_raw(self) -> tuple[int, ...]:
        """The six 16-bit encoder counters [counts, 0..65535]."""
        return _ENCODERS.unpack_from(self._view, vm.ENCODER_OFFSET)

    def write_dacs(self, values: Sequence[float]) -> tuple[int, ...]:
        """Write six amplifier commands [DAC counts], clamped to -2048..2047; returns what was written."""
        if len(values) != vm.N_JOINTS:
            raise ValueError(f"write_dacs needs {vm.N_JOINTS} values, got {len(values)}")
        clamped = tuple(min(vm.DAC_MAX, max(vm.DAC_MIN, int(round(v)))) for v in values)
        vm.store(self._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *clamped)
        return clamped

    def read_dacs(self) -> tuple[int, ...]:
        """The six DAC registers as last written [DAC counts]."""
        return _DACS.unpack_from(self._view, vm.DAC_OFFSET)

    def zero_dacs(self) -> None:
        """Command zero torque on every axis (the shell's on-error action)."""
        vm.store(self._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *([0] * vm.N_JOINTS))

    def read_limit_bits(self) -> int:
        """The limit-switch register: bit j set = joint j+1 switch active."""
        return _U16.unpack_from(self._view, vm.LIMIT_SWITCH_OFFSET)[0]

    def read_limit_switches(self) -> tuple[bool, ...]:
        """Six limit switch states, joint 1 first (True = active)."""
        bits = self.read_limit_bits()
        return tuple(bool(bits >> j & 1) for j in range(vm.N_JOINTS))

    def write_watchdog(self, value0: int, value1: int) -> None:
        """Write both watchdog timer registers (each must change within the timeout)."""
        vm.store(self._view, vm.WATCHDOG_OFFSETS[0], vm.U16_FORMAT, value0 & 0xFFFF)
        vm.store(self._view, vm.WATCHDOG_OFFSETS[1], vm.U16_FORMAT, value1 & 0xFFFF)

    def kick_watchdog(self) -> tuple[int, int]:
        """Write new, different values to both watchdog registers; returns them."""
        self._kick_counter = (self._kick_counter + 1) & 0xFFFF
        values = (self._kick_counter, self._kick_counter ^ 0xFFFF)
        self.write_watchdog(*values)
        return values

    def read_amp_status(self) -> int:
        """AMP_STATUS bits (vme_map.AMP_STATUS_POWERED, AMP_STATUS_WATCHDOG_FAULT)."""
        return _U16.unpack_from(self._view, vm.AMP_STATUS_OFFSET)[0]

    @property
    def amps_powered(self) -> bool:
        """True while the servo amplifiers have power (watchdog not expired)."""
        return bool(self.read_amp_status() & vm.AMP_STATUS_POWERED)

    # -- lifetime ----------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._view is None

    def close(self) -> None:
        """Release the buffer (and the mapping behind it); idempotent."""
        if self._view is None:
            return
        self._view.release()
        self._view = None
        closer, self._closer = self._closer, None
        if closer is not None:
            closer()

    def __enter__(self) -> "VmeBus":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self.closed else "open"
        return f"VmeBus({self.url!r}, {state})"


# -- URL handlers -----------------------------------------------------------------
def _open_shm(url: str, parts) -> VmeBus:
    # shm://NAME : POSIX shared-memory object /NAME, at least MAP_SIZE bytes.
    import posix_ipc

    if parts.query or parts.path or parts.fragment:
        raise VmeUrlError(f"{url}: shm URLs take no path or options; expected {SHM_FORM}")
    name = parts.netloc
    if not _SHM_NAME.match(name):
        raise VmeUrlError(f"{url}: bad shared-memory name; expected {SHM_FORM}")
    try:
        shm = posix_ipc.SharedMemory("/" + name)
    except posix_ipc.ExistentialError:
        raise VmeOpenError(f"{url}: no shared-memory object /{name} (is droid-sim running?)") from None
    except posix_ipc.PermissionsError as exc:
        raise VmeOpenError(f"{url}: {exc}") from None
    try:
        if shm.size < vm.MAP_SIZE:
            raise VmeOpenError(f"{url}: /{name} has {shm.size} bytes, need {vm.MAP_SIZE}")
        region = mmap.mmap(shm.fd, vm.MAP_SIZE)
    finally:
        shm.close_fd()
    return VmeBus(region, closer=region.close, url=url)


def _open_mem(url: str, parts) -> VmeBus:
    # mem:///PATH?offset=0xADDR : mmap of a device or regular file at byte ADDR.
    if parts.netloc or not parts.path.startswith("/") or parts.fragment:
        raise VmeUrlError(f"{url}: expected {MEM_FORM}")
    offset = 0
    for key, value in parse_qsl(parts.query, keep_blank_values=True, strict_parsing=False):
        if key != "offset":
            raise VmeUrlError(f"{url}: unknown option {key!r}; expected {MEM_FORM}")
        try:
            offset = int(value, 0)
        except ValueError:
            raise VmeUrlError(f"{url}: offset {value!r} is not an integer; expected {MEM_FORM}") from None
        if offset < 0:
            raise VmeUrlError(f"{url}: offset must be >= 0; expected {MEM_FORM}")
    page_base = offset - offset % mmap.ALLOCATIONGRANULARITY
    length = offset - page_base + vm.MAP_SIZE
    try:
        fd = os.open(parts.path, os.O_RDWR | os.O_SYNC)
    except OSError as exc:
        raise VmeOpenError(f"{url}: cannot open {parts.path}: {exc.strerror}") from None
    try:
        if os.path.isfile(parts.path) and os.fstat(fd).st_size < offset + vm.MAP_SIZE:
            raise VmeOpenError(f"{url}: {parts.path} is shorter than offset + {vm.MAP_SIZE} bytes")
        region = mmap.mmap(fd, length, offset=page_base)
    except OSError as exc:
        raise VmeOpenError(f"{url}: cannot map {parts.path}: {exc}") from None
    finally:
        os.close(fd)
    window = memoryview(region)[offset - page_base:]

    def closer() -> None:
        window.release()
        region.close()

    return VmeBus(window, closer=closer, url=url)


SCHEMES: dict[str, Callable[[str, object], VmeBus]] = {"shm": _open_shm, "mem": _open_mem}


def open_vme(url: str) -> VmeBus:
    """Open the register map named by ``url`` (see the module docstring for the forms)."""
    parts = urlsplit(url)
    handler = SCHEMES.get(parts.scheme)
    if handler is None or "://" not in url:
        raise VmeUrlError(f"{url!r}: unsupported VME URL; expected {URL_FORMS}")
    return handler(url, parts)
