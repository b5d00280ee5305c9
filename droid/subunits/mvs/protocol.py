"""The MVS serial line to the Brain (thesis §5.4): grammar, parser, line splitter, client core.

The grammar is shared by the sensor program and the Brain, so it lives in
:mod:`droid.brain.plumbing.sensor_line` (imports flow kinematics <- brain <- subunits);
this module re-exports it for the sensor program and its tests.  See that
module and docs/mvs.md "Serial line grammar".
"""
from __future__ import annotations

from droid.brain.plumbing.sensor_line import (INVALID, Garbled, LineSplitter, LineReading, SensorClientCore,
                                     format_line, parse_line, seam_transform)

__all__ = ["INVALID", "Garbled", "LineSplitter", "LineReading", "SensorClientCore", "format_line",
           "parse_line", "seam_transform"]
