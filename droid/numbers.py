"""A number read from a file, checked once: finite, of the right kind, inside a stated range with
its unit (issue 16, "Bad input"; DESIGN §6).

TOML has ``nan``, ``inf`` and ``-inf`` literals and takes ``1e308``, so a cell, layout,
workpiece, robot or plan file can hand a loader any of them.  Every numeric key a loader
reads goes through :meth:`Range.check` (or :func:`droid.cli.file_number`, which turns the
error into a :class:`droid.cli.BadInput`: exit 2, one line naming the file, the key and the
reason).  The same :class:`Range` is what a command-line option of the same quantity
parses with (``droid.cli.bounded_float`` / ``bounded_int`` carry one as ``.range``), so a
rule and its description are written once.

This module imports nothing of droid: ``droid.kinematics`` (which imports nothing else of
droid, DESIGN §7) checks robot files with it too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: The standard serial rates [baud]: POSIX termios's B50..B4000000, as pyserial's
#: ``SerialBase.BAUDRATES`` lists them.
STANDARD_BAUDS = (50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400, 57600,
                  115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000, 1500000, 2000000,
                  2500000, 3000000, 3500000, 4000000)


class NumberError(ValueError):
    """A number of a file that is not one, not finite, of the wrong kind or out of its range.
    The message is one line: ``KEY = VALUE: why (the range)``."""


def _show(value) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
    return repr(value)


@dataclass(frozen=True)
class Range:
    """The numbers a key accepts: ``[lo, hi] unit`` (``lo_open``: ``(lo, hi]``), integers only
    if ``integral``; ``values`` (if given) the only ones accepted inside it (serial rates)."""

    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False
    integral: bool = False
    values: tuple = ()
    values_name: str = ""

    @property
    def span(self) -> str:
        u = f" {self.unit}" if self.unit else ""
        if self.integral:
            text = f"[{int(self.lo)}, {int(self.hi)}]{u}"
        else:
            text = f"{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]{u}"
        return f"{text}, {self.values_name}" if self.values else text

    def reason(self, value) -> str | None:
        """Why ``value`` (as a file or a parser gives it) is refused, or None."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"must be {'an integer' if self.integral else 'a number'} in {self.span}"
        if self.integral and not isinstance(value, int):
            return f"must be an integer in {self.span}"
        if isinstance(value, float) and not math.isfinite(value):
            return f"must be a finite number in {self.span}"
        low = value <= self.lo if self.lo_open else value < self.lo
        if low or value > self.hi:
            return f"is outside {self.span}"
        if self.values and value not in self.values:
            return f"is not one of the {self.values_name} ({', '.join(map(str, self.values))})"
        return None

    def check(self, value, key: str):
        """``value`` (negative zero as zero; an integer of a float key as a float) or
        :class:`NumberError` ``KEY = VALUE: why``."""
        why = self.reason(value)
        if why:
            raise NumberError(f"{key} = {_show(value)}: {why}")
        return value if self.integral else float(value) + 0.0

    def check_all(self, values, key: str, n: int | None = None) -> list:
        """A list of ``n`` (any number if None) such numbers; :class:`NumberError` naming the key and index."""
        if not isinstance(values, list) or (n is not None and len(values) != n):
            count = f"{n} " if n is not None else ""
            raise NumberError(f"{key}: must be a list of {count}numbers in {self.span}")
        return [self.check(v, f"{key}[{i}]") for i, v in enumerate(values)]


def baud_range(lo: int) -> Range:
    """The standard serial rates from ``lo`` to 4 000 000 baud."""
    if lo not in STANDARD_BAUDS:
        raise ValueError(f"{lo} is not a standard rate")
    return Range(lo, STANDARD_BAUDS[-1], "baud", integral=True,
                 values=tuple(b for b in STANDARD_BAUDS if b >= lo), values_name="standard rates")


#: Lengths and positions in a cell, a layout, a workpiece, a robot: within 100 m [mm].
MM = Range(-1e5, 1e5, "mm")
#: A positive length [mm] up to 100 m.
MM_POSITIVE = Range(0.0, 1e5, "mm", lo_open=True)
#: Angles of poses and joints: within ten turns [deg].
DEG = Range(-3600.0, 3600.0, "deg")
