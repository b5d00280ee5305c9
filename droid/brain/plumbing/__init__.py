"""droid.brain.plumbing -- how bytes get between hosts and devices (docs/design.md §7).

The ZeroMQ wire formats (``wire``), the Brain <-> agent link state machines (``link``),
CURVE keys and authentication (``curve``), and the serial side: the line splitter
(``serial_line``), the reopening port (``serial_port``) and the line-laser sensor's line
grammar (``sensor_line``).  Imports nothing of the Brain's other subpackages but the
database name check that ``curve`` shares with the shared-memory objects (``db.shmdb``).
"""
