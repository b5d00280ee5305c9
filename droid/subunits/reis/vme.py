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

import struct
from typing import Callable, Sequence

from droid import kernel as _kernel_switch
from droid.subunits.regmap import MapUnavailable, MapUrlError, open_region
from droid.subunits.reis import vme_map as vm

_ENCODERS = struct.Struct(vm.ENCODERS_FORMAT)
_DACS = struct.Struct(vm.DACS_FORMAT)
_U16 = struct.Struct(vm.U16_FORMAT)
_I16 = struct.Struct(vm.I16_FORMAT)
_SWITCH_MASK = (1 << vm.N_JOINTS) - 1
# the six switch states of every limit-switch register value (a table lookup per servo tick)
_SWITCH_STATES = tuple(tuple(bool(bits >> j & 1) for j in range(vm.N_JOINTS)) for bits in range(1 << vm.N_JOINTS))

#: the register-map errors shared by every driver (droid.subunits.regmap), under the names
#: this driver has always used
VmeUrlError = MapUrlError
VmeOpenError = MapUnavailable


_K = _kernel_switch.compiled()  # droid._kernel when it is in use (droid.kernel), else None


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

    @property
    def registers(self) -> memoryview:
        """The register map's bytes (a writable byte view): for the servo's one-call tick
        (droid.subunits.reis.servo.ServoCore.step_registers)."""
        return self._view

    # -- raw registers ---------------------------------------------------
    def _check(self, offset: int) -> None:
        if offset % vm.REGISTER_BYTES or not 0 <= offset <= vm.MAP_SIZE - vm.REGISTER_BYTES:
            raise ValueError(f"register offset {offset:#x} not an aligned offset below {vm.MAP_SIZE:#x}")

    # Deliberate: one accessor per register width and sign, as the register map names them.
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
        if _K is not None:  # the compiled kernel: six ints clamped and stored
            written = _K.write_dacs(self._view, values)
            if written is not None:
                return written
        hi, lo = vm.DAC_MAX, vm.DAC_MIN
        clamped = tuple([min(hi, max(lo, int(round(v)))) for v in values])
        self._view[vm.DAC_OFFSET:vm.DAC_OFFSET + _DACS.size] = _DACS.pack(*clamped)  # vm.store's one copy
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
        return _SWITCH_STATES[_U16.unpack_from(self._view, vm.LIMIT_SWITCH_OFFSET)[0] & _SWITCH_MASK]

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


# -- opening by URL (droid.subunits.regmap: one table of shm:// / mem:// handlers) --------
def open_vme(url: str) -> VmeBus:
    """Open the register map named by ``url`` (see the module docstring for the forms)."""
    region = open_region(url, vm.MAP_SIZE, "VME")
    try:
        return VmeBus(region.buf, closer=region.close, url=url)
    except BaseException:
        region.close()
        raise
