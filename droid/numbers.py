"""A number read from a file, checked once: finite, of the right kind, inside a stated range with
its unit (issue 16, "Bad input"; docs/design.md §6).

TOML has ``nan``, ``inf`` and ``-inf`` literals and takes ``1e308``, so a cell, layout,
workpiece, robot or plan file can hand a loader any of them.  Every numeric key a loader
reads goes through :meth:`Range.check` (or :func:`droid.cli.file_number`, which turns the
error into a :class:`droid.cli.BadInput`: exit 2, one line naming the file, the key and the
reason).  The same :class:`Range` is what a command-line option of the same quantity
parses with (``droid.cli.bounded_float`` / ``bounded_int`` carry one as ``.range``), so a
rule and its description are written once.

This module imports nothing of droid: ``droid.kinematics`` (which imports nothing else of
droid, docs/design.md §7) checks robot files with it too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: The standard serial rates [baud]: POSIX termios's B50..B4000000, as pyserial's
#: ``SerialBase.BAUDRATES`` lists them.
STANDARD_BAUDS = (50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400, 57600,
                  115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000, 1500000, 2000000,
                  2500000, 3000000, 3500000, 4000000)


class BadFile(ValueError):
    """A file that is missing or malformed, raised where :class:`droid.cli.BadInput` cannot be
    (``droid.kinematics.RobotFileError``: droid.kinematics imports no droid.cli).  Every program's
    :func:`droid.cli.run` ends with its one-line message and exit 2, as for a BadInput."""


class NumberError(BadFile):
    """A number of a file that is not one, not finite, of the wrong kind or out of its range.
    The message is one line: ``KEY = VALUE: why (the range)``."""


def show_number(value) -> str:
    """A number as TOML writes it (nan, inf, -inf for the non-finite floats)."""
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
    return repr(value)


def finite_numbers(value, n: int) -> bool:
    """``value`` is a list of ``n`` finite numbers (ints or floats; a bool is not a number)."""
    return isinstance(value, list) and len(value) == n and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)


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
            raise NumberError(f"{key} = {show_number(value)}: {why}")
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


# -- the ranges of file keys ----------------------------------------------------------
# A key's range is found by its name (issue 16): its own name in NAMED, else its unit
# suffix in SUFFIXES (the longest that fits), else the same for the tables that hold it
# (``[bases] arm1 = [...]`` is a pose because of ``bases``).  These are outer, physical
# bounds -- a loader may hold a key tighter (heartbeat_hz [1, 1000] Hz, a GMF1's baud) and
# says so in its own message.  ``python -m droid.numbers`` prints the table
# (docs/architecture.md, "Numbers in files").

#: Lengths and positions in a cell, a layout, a workpiece, a robot: within 100 m [mm].
MM = Range(-1e5, 1e5, "mm")
#: Angles of poses and joints: within ten turns [deg].
DEG = Range(-3600.0, 3600.0, "deg")
#: A pose ``[x y z (mm), A B C (ZYZ deg)]``: the range of each element.
POSE = (MM, MM, MM, DEG, DEG, DEG)
#: +1 or -1 (a joint's sign or direction).
SIGN = Range(-1, 1, values=(-1, 1), values_name="signs +1 or -1")
#: Random seeds: what numpy's and the world's generators take (uint32).
SEED = Range(0, 2**32 - 1, integral=True)

SUFFIXES: dict[str, Range] = {
    "_mm": MM,
    "_deg": DEG,
    "_mm_s": Range(0.0, 1e4, "mm/s", lo_open=True),
    "_deg_s": Range(0.0, 1e5, "deg/s", lo_open=True),
    "_rad_s": Range(0.0, 1e5, "rad/s", lo_open=True),
    "_hz": Range(0.0, 1e6, "Hz", lo_open=True),
    "_s": Range(0.0, 86400.0, "s"),
    "_per_s": Range(0.0, 1e6, "1/s"),
    "_kg": Range(0.0, 1e4, "kg"),
    "_kgm2": Range(-1e4, 1e4, "kg m^2"),  # products of inertia have either sign
    "_mps2": Range(-1e3, 1e3, "m/s^2"),
    "_nm": Range(0.0, 1e6, "N m"),
    "_nm_per_rad": Range(0.0, 1e10, "N m/rad"),
    "_nm_s_per_rad": Range(0.0, 1e9, "N m s/rad"),
    "_nm_per_a": Range(0.0, 1e3, "N m/A"),
    "_a_per_v": Range(0.0, 1e3, "A/V"),
    "_a": Range(0.0, 1e4, "A"),
    "_v": Range(0.0, 1e3, "V"),
    "_dac": Range(0.0, 1e6, "DAC units"),
    "_dac_per_count": Range(0.0, 1e6, "DAC units/count"),
    "_dac_per_count_tick": Range(0.0, 1e6, "DAC units/(count tick)"),
    "_dac_per_count_per_tick": Range(0.0, 1e6, "DAC units tick/count"),
    "_px": Range(0.0, 1e4, "px"),
    "_ticks": Range(1, 10**6, "ticks", integral=True),
    "_cycles": Range(0, 108000, "cycles", integral=True),
    "_seed": SEED,
    "_probability": Range(0.0, 1.0),
    "_fraction": Range(0.0, 1.0),
    "_gain": Range(0.0, 10.0),
    "_mm_per_row": Range(0.0, 1e3, "mm/row", lo_open=True),
    "_mm_per_column": Range(0.0, 1e3, "mm/column", lo_open=True),
}

NAMED: dict[str, Range | tuple] = {
    "seed": SEED,
    "baud": baud_range(50),
    "base": POSE, "bases": POSE, "mount": POSE, "fixture": POSE, "workpiece_mount": POSE,
    "tool_pose": POSE, "contact_tool_pose": POSE, "contact_workpiece_pose": POSE, "touch_pose": POSE,
    "workpiece_pose": POSE,
    # the world's contact device (droid.sim.contact_device)
    "plate_mm": Range(0.0, 1e3, "mm", lo_open=True),
    "max_closing_speed_mm_s": Range(0.0, 1e6, "mm/s", lo_open=True),
    "sensor_pose": POSE, "sensor_tool_pose": POSE, "ft_pose": POSE,
    "pose": POSE,  # the collision guard's boxes ([guard] workpiece, fixtures: docs/guard.md)
    "signs": SIGN, "direction": SIGN, "search_dir": SIGN,
    "reduction": Range(0.0, 1e5, "(gear ratio)", lo_open=True),
    "encoder_counts_per_rev": Range(0.0, 1e9, "counts/rev", lo_open=True),
    "encoder_bits": Range(2, 62, "bits", integral=True),
    "coupling": Range(-10.0, 10.0, "(joint/joint)"),
    "counts_min": Range(-2**31, 2**31 - 1, "counts", integral=True),
    "counts_max": Range(-2**31, 2**31 - 1, "counts", integral=True),
    "weights": Range(0.0, 1e6, "(planner weight)"),
    "velocity_feedforward": Range(0.0, 10.0, "(fraction)"),
    "balancer_moment_nm": Range(-1e6, 1e6, "N m"),
    "roll_profile": (MM, DEG),  # [s (mm), roll (deg)] pairs
    "step_profile": (MM, MM),  # [s (mm), step (mm)] pairs
    "axes": Range(0, 1024, "axes", integral=True), "buttons": Range(0, 1024, "buttons", integral=True),
    "row_at_origin": Range(-1e4, 1e4, "rows"), "column_at_origin": Range(-1e4, 1e4, "columns"),
    # a workpiece's [contact] (droid.sim.contact; docs/contact.md): from a foam pad to a stiff steel tool mount
    "stiffness_n_per_mm": Range(0.0, 1e5, "N/mm", lo_open=True),
    "damping_n_s_per_mm": Range(0.0, 1e3, "N s/mm"),
    "friction_coefficient": Range(0.0, 2.0),
    # the force task's gains (droid/tasks/contact/gains.toml)
    "admittance_mm_per_n_s": Range(0.0, 1e3, "mm/(N s)", lo_open=True),
    "force_n": Range(0.0, 1e4, "N", lo_open=True),
    "force_max_n": Range(0.0, 1e4, "N", lo_open=True),
    "contact_lost_n": Range(0.0, 1e4, "N"),
    "touch_n": Range(0.0, 1e4, "N", lo_open=True),
    "contact_stiffness_n_per_mm": Range(0.0, 1e5, "N/mm", lo_open=True),
}


def _suffix_range(key: str):
    best = ""
    for suffix in SUFFIXES:
        if key.endswith(suffix) and len(suffix) > len(best):
            best = suffix
    return SUFFIXES[best] if best else None


def _by_name(key: str):
    return NAMED[key] if key in NAMED else _suffix_range(key)


def range_of(path: tuple):
    """The :class:`Range` of the number at ``path`` (keys and list indices from the top of a
    file), or None if none of its keys states one.

    Which key speaks for the number, in this order: its own key by name (``baud``); the nearest
    enclosing key by name, for tables whose entries are named by the user (``bases.arm1``,
    ``fixture.tool``); its own key by unit suffix (``speed_mm_s``).  An enclosing key's unit
    suffix never counts: enclosing keys are often names a user chose (a subunit ``arm_a``, a
    world device ``joy_a``), and a name is not a unit."""
    strings = [p for p in path if isinstance(p, str)]
    if not strings:
        return None
    own = strings[-1]
    found = NAMED.get(own)
    if found is None:
        found = next((NAMED[p] for p in reversed(strings[:-1]) if p in NAMED), None)
    if found is None:
        found = _suffix_range(own)
    if isinstance(found, tuple):
        i = next((p for p in reversed(path) if isinstance(p, int)), 0)
        return found[i] if i < len(found) else None
    return found


def key_name(path: tuple) -> str:
    """``table.key[i]`` -- how an error names the number at ``path``."""
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def check_numbers(data, path: tuple = ()) -> None:
    """Check every number of a parsed file (a TOML dict) against its key's range (:func:`range_of`);
    :class:`NumberError` ``table.key[i] = VALUE: why RANGE`` for the first that is not finite, of
    the wrong kind or outside.  Numbers of keys with no stated range are left to the loader (which
    refuses unknown keys); a key whose range is integral also refuses a float there."""
    if isinstance(data, dict):
        for k, v in data.items():
            check_numbers(v, (*path, k))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            check_numbers(v, (*path, i))
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        rng = range_of(path)
        if rng is not None:
            rng.check(data, key_name(path))
        elif isinstance(data, float) and not math.isfinite(data):
            raise NumberError(f"{key_name(path)} = {show_number(data)}: must be a finite number")


def table() -> str:
    """The Markdown table of the ranges by key name and unit suffix (docs/architecture.md)."""
    rows = ["| key | range |", "|---|---|"]
    for name, r in NAMED.items():
        if isinstance(r, tuple):  # per element: "3 x [..] mm, 3 x [..] deg"
            groups: list[list] = []
            for x in r:
                if groups and groups[-1][0] == x:
                    groups[-1][1] += 1
                else:
                    groups.append([x, 1])
            spans = ", ".join(f"{n} x `{x.span}`" if n > 1 else f"`{x.span}`" for x, n in groups)
            rows.append(f"| `{name}` | {spans} (per element) |")
        else:
            rows.append(f"| `{name}` | `{r.span}` |")
    for suffix, r in SUFFIXES.items():
        rows.append(f"| `*{suffix}` | `{r.span}` |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    import sys

    sys.stdout.write(table())
