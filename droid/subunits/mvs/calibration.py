"""Pixel <-> millimetre calibration of the MVS line-laser sensor (thesis §5.4).

sensor.exe "begins by initializing the calibration coefficients ... [which]
allow the pixel data to be converted into real-world coordinates".  Here the
conversion is linear and separable, in the sensor frame S (docs/mvs.md):

    y_mm = (row    - row_at_origin)    * lateral_mm_per_row     (lateral)
    x_mm = (column - column_at_origin) * depth_mm_per_column    (depth, + = farther)

The defaults give a field of view of +-24 mm lateral (240 rows x 0.2 mm) and
+-25.6 mm depth (512 columns x 0.1 mm) about the nominal measuring point.
A real triangulation sensor's depth calibration is not linear (it follows the
camera's perspective); a table or polynomial would replace :meth:`to_mm`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from droid.cli import BadInput
from droid.numbers import NumberError, check_numbers
from droid.subunits.mvs.wire import COLUMNS, ROWS


@dataclass(frozen=True)
class MvsCalibration:
    """Linear pixel <-> mm constants (see the module docstring)."""

    lateral_mm_per_row: float = 0.2
    depth_mm_per_column: float = 0.1
    row_at_origin: float = (ROWS - 1) / 2.0
    column_at_origin: float = (COLUMNS - 1) / 2.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                raise BadInput(f"calibration {f.name} must be a finite number, got {value!r}")
        if self.lateral_mm_per_row <= 0 or self.depth_mm_per_column <= 0:
            raise BadInput("calibration scales (lateral_mm_per_row, depth_mm_per_column) must be > 0")

    def to_mm(self, row: float, column: float) -> tuple[float, float]:
        """(x_mm depth, y_mm lateral) in S of a (fractional) row and column."""
        return ((column - self.column_at_origin) * self.depth_mm_per_column,
                (row - self.row_at_origin) * self.lateral_mm_per_row)

    def row_of(self, y_mm):
        """Fractional row of a lateral position y [mm] (numbers or arrays)."""
        return self.row_at_origin + y_mm / self.lateral_mm_per_row

    def column_of(self, x_mm):
        """Fractional column of a depth x [mm] (numbers or arrays)."""
        return self.column_at_origin + x_mm / self.depth_mm_per_column

    def lateral_of(self, row):
        """Lateral y [mm] of a (fractional) row (numbers or arrays)."""
        return (row - self.row_at_origin) * self.lateral_mm_per_row

    def slope_to_roll(self, columns_per_row: float) -> float:
        """Surface roll [rad] about S's z from a profile slope d(column)/d(row).

        The profile is x = -tan(roll) * y (docs/mvs.md), so
        roll = -atan(dx/dy) = -atan(slope * depth_mm_per_column / lateral_mm_per_row).
        """
        return -math.atan(columns_per_row * self.depth_mm_per_column / self.lateral_mm_per_row)

    @classmethod
    def from_table(cls, table: dict, source: str = "calibration") -> "MvsCalibration":
        """Build from a TOML table (e.g. a cell file's sensor ``calibration`` section)."""
        known = {f.name for f in fields(cls)}
        for key in table:
            if key not in known:
                raise BadInput(f"{source}: unknown calibration key {key!r} (expected {', '.join(sorted(known))})")
        try:
            check_numbers(table)  # finite and inside each key's range (droid.numbers, issue 16)
        except NumberError as exc:
            raise BadInput(f"{source}: {exc}") from None
        return cls(**table)
