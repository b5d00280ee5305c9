"""Register map of the Reis Robotstar V15 VMEbus interface cards (thesis §4.1.2).

The two interface expansion cards map into VMEbus memory: six 16-bit encoder
counters, six signed 12-bit DACs (one per servo amplifier), the joint limit
switches and two watchdog timer registers.  The original cards' addresses are
not given in the thesis, so DROID fixes one plain byte layout here; the
simulated robot (droid/sim) lays out its POSIX shared-memory object with the
same constants, and a real card is reached with ``mem://...?offset=`` pointing
at its base address.

All registers are 16 bits wide, little-endian, 2-byte aligned::

    offset  name             type  access  meaning
    0x00    ENCODER[0..5]    u16   r (w)   motor encoder counters [counts], wrap at 2**16;
                                           a write resets that counter to 0 (not used)
    0x10    DAC[0..5]        i16   w       amplifier command [DAC counts], -2048..2047
                                           (12-bit signed; +-5 V at the amplifier input)
    0x20    LIMIT_SWITCHES   u16   r       bit j set = joint j+1 limit switch active
    0x24    WATCHDOG[0]      u16   w       timer 0: must change value within the timeout
    0x26    WATCHDOG[1]      u16   w       timer 1: same
    0x28    AMP_STATUS       u16   r       bit 0 amplifiers powered, bit 1 watchdog fault
                                           latched (DROID addition; see docs/reis.md)
    0x2A..0x3F                             reserved, read as 0

``MAP_SIZE`` bytes in all.  Joint index j is 0-based in code (joint j+1 in the
thesis).
"""
from __future__ import annotations

import struct

N_JOINTS = 6

ENCODER_OFFSET = 0x00  # 6 x u16
DAC_OFFSET = 0x10  # 6 x i16
LIMIT_SWITCH_OFFSET = 0x20  # u16 bit field
WATCHDOG_OFFSETS = (0x24, 0x26)  # 2 x u16
AMP_STATUS_OFFSET = 0x28  # u16 bit field
MAP_SIZE = 0x40  # bytes

REGISTER_BYTES = 2
ENCODER_BITS = 16
ENCODER_MODULUS = 1 << ENCODER_BITS  # counts

DAC_BITS = 12
DAC_MIN = -(1 << (DAC_BITS - 1))  # -2048 DAC counts
DAC_MAX = (1 << (DAC_BITS - 1)) - 1  # 2047 DAC counts
DAC_FULL_SCALE_V = 5.0  # amplifier input at DAC_MAX+1 [V] (thesis §2.3: "+5VDC")

AMP_STATUS_POWERED = 0x0001
AMP_STATUS_WATCHDOG_FAULT = 0x0002

# struct formats (little-endian)
ENCODERS_FORMAT = "<6H"
DACS_FORMAT = "<6h"
U16_FORMAT = "<H"
I16_FORMAT = "<h"


_STRUCTS: dict[str, "struct.Struct"] = {}


def store(view, offset: int, fmt: str, *values) -> None:
    """Write registers as ONE copy of pre-packed bytes.

    Never ``struct.pack_into`` on a shared map: CPython's pack_into first
    memsets the destination to zero and then fills it in, so a reader in
    another process can see a register read 0 for an instant (seen in the
    real-time cell as a spurious ENCODER_JUMP fault).  A slice assignment is
    one memcpy: a concurrent reader sees each 16-bit register old or new.
    """
    s = _STRUCTS.get(fmt)
    if s is None:
        s = _STRUCTS[fmt] = struct.Struct(fmt)
    view[offset:offset + s.size] = s.pack(*values)
