"""Register map of one CIO-QUAD04-like 4-channel quadrature encoder card (thesis §2.4, Fig. 2.7).

The GMF1 interface computer reads the six joint encoders of the Fanuc S400
through two such cards (§4.2.5).  The real card is an ISA board of LS7266R1
counter chips reached by port I/O; this map keeps what the encoder program
needs from it (24-bit up/down counters, an output latch, a counter reset) as
little-endian 32-bit words in a 128-byte block, so the same bytes can sit in a
POSIX shared-memory object (droid-sim's twin) or in a memory-mapped window of
a real adapter.

=======  ====  =========  ======================================================
offset   size  name       meaning
=======  ====  =========  ======================================================
0x00     4     MAGIC      ``b"QD04"`` (0x34304451 little-endian)
0x04     2     VERSION    map version (1)
0x06     2     CHANNELS   4
0x08     4     STATUS     bit 0 POWER: the card counts
0x0C     4     reserved
0x10+16c 4     COUNT      channel c's live counter, 24 bits (bits 24-31 read 0)
0x14+16c 4     LATCH      output latch: COUNT at the last CMD_LATCH
0x18+16c 4     CTRL       command register: write CMD_LATCH or CMD_RESET; the
                          card executes it, clears CTRL to 0 and adds 1 to DONE
0x1C+16c 4     DONE       commands executed on this channel (wraps at 2**32)
=======  ====  =========  ======================================================

Counters wrap modulo 2**24 (the reader extends them,
:func:`droid.kinematics.extend_counters`).  At power-up they hold arbitrary
values.  CMD_RESET sets the counter to 0 (the encoder program does this once
the controller has reached its home pose: ``droid-home``, docs/gmf1.md).

Joints are wired card by card: joint ``i`` (0-based) is card ``i // 4``,
channel ``i % 4``; card 1's channels 2 and 3 are unused.
"""
from __future__ import annotations

import struct
import sys

MAGIC = 0x34304451  # b"QD04" little-endian
VERSION = 1
CHANNELS = 4
MAP_SIZE = 128
COUNTER_BITS = 24
COUNTER_MASK = (1 << COUNTER_BITS) - 1

OFF_MAGIC = 0x00
OFF_VERSION = 0x04
OFF_CHANNELS = 0x06
OFF_STATUS = 0x08
OFF_CHANNEL0 = 0x10
CHANNEL_STRIDE = 16
REG_COUNT = 0
REG_LATCH = 4
REG_CTRL = 8
REG_DONE = 12

STATUS_POWER = 1

CMD_NONE = 0
CMD_LATCH = 1
CMD_RESET = 2

JOINTS = 6
CARDS = 2


def channel_offset(ch: int, reg: int) -> int:
    """Byte offset of register ``reg`` (REG_*) of channel ``ch`` (0..3)."""
    if not 0 <= ch < CHANNELS:
        raise ValueError(f"channel {ch} outside 0..{CHANNELS - 1}")
    return OFF_CHANNEL0 + CHANNEL_STRIDE * ch + reg


def joint_channel(joint: int) -> tuple[int, int]:
    """(card, channel) wired to joint ``joint`` (0-based)."""
    if not 0 <= joint < JOINTS:
        raise ValueError(f"joint {joint} outside 0..{JOINTS - 1}")
    return joint // CHANNELS, joint % CHANNELS


HEADER = struct.Struct("<IHHI")  # magic, version, channels, status
CHANNEL_BLOCK = struct.Struct("<" + "IIII" * CHANNELS)  # COUNT LATCH CTRL DONE x 4
U32 = struct.Struct("<I")


def format_header(buf, power: bool = True) -> None:
    """Write the identification words of an empty card into ``buf`` (the card side)."""
    HEADER.pack_into(buf, 0, MAGIC, VERSION, CHANNELS, STATUS_POWER if power else 0)


def words(buf) -> memoryview:
    """The map ``buf`` as 32-bit words (a memoryview cast to ``I``) whose item assignment is one
    4-byte store.  Write registers through it, never with ``struct.pack_into``: pack_into zeroes
    its bytes before it writes the value, and a reader in another process (droid-gmf1-encoder
    against droid-sim's twin) catches that 0 -- a COUNT read as 0 is the joint at home for one
    cycle (the 26 deg step droid-guard stopped the abb_weld cell on)."""
    if sys.byteorder != "little":
        raise RuntimeError("the encoder card map is little-endian: a word view needs a little-endian host")
    return memoryview(buf)[:MAP_SIZE].cast("I")
