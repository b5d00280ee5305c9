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
# Defined once in droid.brain.plumbing.sensor_line (the Brain parses what the sensor writes).
from droid.brain.plumbing.sensor_line import (BITS_PER_BYTE, DEFAULT_BAUD, INVALID_LINE, LINE_END,  # noqa: E402,F401
                                     MAX_LINE_BYTES, MIN_BAUD, ROLL_DECIMALS, X_DECIMALS)
