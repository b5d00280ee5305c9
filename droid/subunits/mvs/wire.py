"""Wire and layout constants of the MVS line-laser sensor (thesis §5.3-5.4).

One module for every number that both ends of a link must agree on: the DSP
board's frame geometry and shared-memory layout, and the serial line grammar
between droid-mvs and the Brain.
"""
from __future__ import annotations

import numpy as np

# -- the DSP board's output (thesis §5.3) ---------------------------------------
#: Stripe rows per frame (one field of the 512 x 480 interlaced RS-170 image).
ROWS = 240
#: Columns per row; a stripe column is 0..COLUMNS-1.
COLUMNS = 512
#: Frames (vertical retraces) per second.
FRAME_RATE_HZ = 60.0
#: Column value of a row with no stripe (any negative value means the same).
NO_STRIPE = -1

# -- the shared-memory frame buffer of the simulated DSP board -------------------
DSP_MAGIC = 0x4453564D  # b"MVSD" little-endian
DSP_LAYOUT_VERSION = 1
#: Suffix of the named semaphore posted at each vertical retrace.
RETRACE_SUFFIX = ".retrace"

#: Frame buffer record (little-endian, fixed layout).  ``sequence`` is a
#: seqlock: odd while the writer copies rows in, even when the frame is whole;
#: ``frames`` counts whole frames written since the board was created.
DSP_RECORD = np.dtype(
    [
        ("magic", "<u4"),
        ("version", "<u2"),
        ("rows", "<u2"),
        ("columns", "<u2"),
        ("reserved", "<u2"),
        ("writer_pid", "<i4"),
        ("sequence", "<u8"),
        ("frames", "<u8"),
        ("timestamp_ns", "<u8"),
        ("stripe", "<i2", (ROWS,)),
    ]
)

# -- the serial line to the Brain (thesis §5.4: comma-delimited ASCII) ------------
#: A valid line: "x,y,roll\n" with x, y in mm (3 decimals) and roll in rad (5 decimals).
X_DECIMALS = 3
ROLL_DECIMALS = 5
#: The line sent for a frame without a feature.
INVALID_LINE = b"invalid"
LINE_END = b"\n"
#: Longest line the grammar allows ("-9999.999,-9999.999,-3.14159" + "\r").
MAX_LINE_BYTES = 32
#: Lowest baud rate accepted.  A line for a feature inside the default field of
#: view is at most 25 bytes ("-25.600,-24.000,-1.57080\n"): 60 lines/s x 25 bytes
#: x 10 bits = 15 000 bit/s, which 9600 baud cannot carry and 19200 can.
MIN_BAUD = 19200
DEFAULT_BAUD = 19200
BITS_PER_BYTE = 10
