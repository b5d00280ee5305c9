"""Reading the Reis robot data file (droid/kinematics/robots/reis_v15.toml).

Only the ``[gearing]`` table is used here (thesis §4.1.1.3, eq. 4.10-4.14);
the joint-to-counts matrix M (counts = M @ q_deg) comes from
:class:`droid.kinematics.gearing.Gearing`.  Home-switch positions, joint and
speed limits are not in the data file yet: the servo and plant parameter
dataclasses carry DROID's defaults (docs/reis.md).
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import droid.kinematics
from droid.kinematics.gearing import Gearing

ROBOTS_DIR = Path(droid.kinematics.__file__).parent / "robots"
DEFAULT_ROBOT = "reis_v15"


def robot_file_path(robot: str = DEFAULT_ROBOT) -> Path:
    """Path of a robot data file by model name (e.g. ``reis_v15``)."""
    return ROBOTS_DIR / f"{robot}.toml"


def load_gearing(path: str | Path | None = None) -> Gearing:
    """The :class:`Gearing` of a robot data file (default: the Reis V15)."""
    path = Path(path) if path is not None else robot_file_path()
    with open(path, "rb") as f:
        table = tomllib.load(f)
    try:
        return Gearing.from_table(table["gearing"])
    except KeyError as exc:
        raise ValueError(f"{path}: missing gearing entry {exc}") from None


def joint_to_counts_tuple(gearing: Gearing) -> tuple[tuple[float, ...], ...]:
    """M [counts per joint degree] as a hashable 6x6 tuple (for frozen dataclasses)."""
    return tuple(tuple(float(x) for x in row) for row in gearing.joint_to_counts_matrix)


def offset_file(cell, arm: str) -> Path:
    """Where homing finds an arm's calibrated home offsets: ``<run_dir>/<arm>.home_offset.json``
    (written by droid-calibrate, thesis §4.1.1.4; read by droid-servo at start)."""
    return Path(cell.run_dir) / f"{arm}.home_offset.json"


def read_offsets(cell, arm: str) -> list[float] | None:
    """The calibrated home offsets of ``arm`` [deg] (true switch minus the robot file's), or None
    if the arm was not calibrated.  Raises ValueError for a malformed file."""
    import json

    from droid.numbers import finite_numbers

    p = offset_file(cell, arm)
    if not p.is_file():
        return None
    try:
        off = json.loads(p.read_text())["home_offset_deg"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{p}: bad calibration file: {exc}") from None
    if not finite_numbers(off, 6):
        raise ValueError(f"{p}: home_offset_deg must be 6 numbers")
    if max(abs(v) for v in off) > 5.0:
        raise ValueError(f"{p}: home offsets above 5 deg are not calibration offsets")
    return [float(v) for v in off]
