"""Every number of every shipped file (issue 16, "Bad input"; docs/design.md §6).

TOML has ``nan``, ``inf`` and ``-inf`` literals and takes ``1e308``: numbers in cell files,
robot files, seam-tracking layouts, workpieces and experiment plans are real input.  The
files are not listed key by key: every ``.toml`` the package ships is read, every number in it
found by walking the parsed file (tests/hostile/filewalk.py), and each is replaced in a copy
by nan, inf, -inf, 1e308, -1e308, a negative where its key's range starts at 0 or above, and
(for an integer key) 1.5 and a string.  The loader must refuse each copy with its clean error
(:class:`droid.cli.BadInput`; :class:`droid.kinematics.RobotFileError` for robot files, which
programs turn into BadInput) in one line naming the key -- never a traceback, never accepted.

The ranges are stated once, by key name and unit suffix, in :mod:`droid.numbers`;
:func:`test_every_number_has_a_stated_range` fails when a shipped file gains a number whose
key states none.  The loaders run in this process (fast); a few subprocess runs of programs
that read such a file before they start anything check exit 2 and the one line on stderr.
"""
from __future__ import annotations

import math
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from droid import numbers
from droid.brain.cell.cellfile import load_cell
from droid.brain.db.shmdb import cell_objects
from droid.cli import BadInput
from droid.kinematics import RobotFileError, load_robot
from tests.hostile.filewalk import dumps, key_of, leaves, replaced

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "droid"


def check_cell(path) -> None:
    """Everything a cell's programs read of a cell file before they start: the file, every
    subunit's own keys, its robot file, and the world (built and closed: shared memory and ptys
    under the cell's unique name, no process, nothing moves)."""
    from droid.brain.runtime.sensor_link import link_kind, serial_link_options
    from droid.sim.world import WORLD_RATE_HZ, build_world
    from droid.subunits.gmf1.config import gmf1_config
    from droid.subunits.joystick.prog import joystick_options
    from droid.subunits.ft.prog import ft_options
    from droid.subunits.mvs.sensor import cell_calibration
    from droid.cli import file_number

    cell = load_cell(path)
    for sub in cell.subunits.values():
        if sub.robot:
            load_robot(sub.robot)
        if any(p.startswith("droid-gmf1") for p in sub.programs):
            gmf1_config(cell, sub)
        if sub.cls == "line_laser":
            if link_kind(cell, sub) == "serial":
                serial_link_options(cell, sub)
            if "droid-mvs" in sub.programs:
                cell_calibration(sub, f"[subunits.{sub.name}]")
        if sub.cls == "joystick":
            joystick_options(sub)
        if sub.cls == "ft6":
            ft_options(sub, cell)
    if cell.world.get("enabled", True):
        file_number(cell.world.get("rate_hz", 1000.0), WORLD_RATE_HZ, "[world]", "rate_hz")
        build_world(cell).close()


def _loaders():
    from droid.experiments.plan import load_plan
    from droid.sim.workpiece import load_workpiece
    from droid.tasks.contact.core import load_gains
    from droid.brain.cell.cell_layout import load_layout

    return {"robot": load_robot, "workpiece": load_workpiece, "layout": load_layout, "plan": load_plan,
            "cell": check_cell, "gains": load_gains}


def _kind(path: Path) -> str:
    if path.parent.name == "robots":
        return "robot"
    if path.parent.name == "workpieces":
        return "workpiece"
    if path.parent.name == "plans":
        return "plan"
    if path.name == "gains.toml":  # the force task's gains (droid.tasks.contact)
        return "gains"
    return "layout" if "layout" in path.name else "cell"


SHIPPED = sorted(p for p in PKG.rglob("*.toml"))
IDS = [str(p.relative_to(PKG)) for p in SHIPPED]


def test_the_shipped_files_were_all_found():
    kinds = {_kind(p) for p in SHIPPED}
    assert kinds == {"robot", "workpiece", "layout", "plan", "cell", "gains"}, kinds
    assert len(SHIPPED) >= 15


def _all_numbers(data, path=()):
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _all_numbers(v, (*path, k))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            yield from _all_numbers(v, (*path, i))
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        yield path, data


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_every_number_has_a_stated_range(path):
    """Every number of a shipped file has a range by its key (droid.numbers) that holds it."""
    data = tomllib.loads(path.read_text())
    for p, v in _all_numbers(data):
        rng = numbers.range_of(p)
        assert rng is not None, f"{path.name}: {numbers.key_name(p)} = {v!r} has no stated range: " \
                                f"give its key a unit suffix or a NAMED entry in droid/numbers.py"
        assert rng.reason(v) is None, (path.name, numbers.key_name(p), v, rng.span)


def _hostile(path: tuple, value) -> list:
    rng = numbers.range_of(path)
    vals = [math.nan, math.inf, -math.inf, 1e308, -1e308]
    if rng is not None and rng.integral:
        vals += [1.5, "x"]
    if rng is not None and rng.lo >= 0:
        vals.append(-max(abs(value), 1))
    return vals


@pytest.fixture
def copy_of(tmp_path, cell_name):
    """A writable copy of a shipped file's directory (relative references keep working); a cell is
    renamed to this test's unique name with its run directory in tmp."""
    def make(path: Path):
        dst_dir = tmp_path / "files"
        shutil.copytree(path.parent, dst_dir)
        data = tomllib.loads(path.read_text())
        if _kind(path) == "cell":
            data["cell"]["name"] = cell_name
            data["cell"]["run_dir"] = str(tmp_path / "run")
        return dst_dir / path.name, data
    return make


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_hostile_numbers_are_refused_naming_the_key(path, copy_of, cell_name):
    load = _loaders()[_kind(path)]
    dst, data = copy_of(path)
    dst.write_text(dumps(data))
    load(str(dst))  # the copy as written is accepted: only the number under test differs below
    tried = 0
    for p, value in leaves(data):
        key = key_of(p)
        for bad in _hostile(p, value):
            dst.write_text(dumps(replaced(data, p, bad)))
            tried += 1
            try:
                load(str(dst))
            except (BadInput, RobotFileError) as exc:
                msg = str(exc)
                assert "\n" not in msg and key in msg, (numbers.key_name(p), bad, msg)
            else:
                pytest.fail(f"{path.name}: {numbers.key_name(p)} = {bad!r} was accepted")
    assert tried >= 10
    assert cell_objects(cell_name) == []


def test_the_documented_table_is_the_modules_own():
    doc = (ROOT / "docs" / "architecture.md").read_text()
    assert numbers.table() in doc, \
        "docs/architecture.md, Numbers in files: paste the table of 'python -m droid.numbers'"


def test_the_range_of_a_pose_is_per_element():
    assert numbers.range_of(("subunits", "gmf1", "base", 0)).unit == "mm"
    assert numbers.range_of(("subunits", "gmf1", "base", 3)).unit == "deg"
    assert numbers.range_of(("bases", "arm1", 5)).unit == "deg"
    assert numbers.range_of(("speed_mm_s",)).unit == "mm/s"  # the longest suffix, not "_s"
    assert numbers.range_of(("x", "unheard_of")) is None
    with pytest.raises(numbers.NumberError, match=r"^a\.b\[1\] = nan: must be a finite number"):
        numbers.check_numbers({"a": {"b": [0, math.nan]}})


def test_a_name_the_user_chose_is_not_a_unit():
    """Subunit and device names are the user's: ``joy_a`` or ``arm_a`` end like the ampere
    suffix ``_a`` but say nothing of the numbers under them (a joystick script's axes are -1..1)."""
    script = {"world": {"devices": {"joy_a": {"script": [[1.0, [-0.5, 0.25], [0, 1]]]}}}}
    numbers.check_numbers(script)
    assert numbers.range_of(("world", "devices", "joy_a", "script", 0, 1, 0)) is None
    assert numbers.range_of(("bases", "arm_a", 5)).unit == "deg"  # the table's name speaks, not the entry's
    assert numbers.range_of(("subunits", "arm_a", "speed_mm_s")).unit == "mm/s"
    with pytest.raises(numbers.NumberError, match=r"^subunits\.arm_a\.peak_a = -1: is outside"):
        numbers.check_numbers({"subunits": {"arm_a": {"peak_a": -1}}})


@pytest.mark.parametrize("key", ["lateral_mm_per_row", "depth_mm_per_column", "row_at_origin", "column_at_origin"])
@pytest.mark.parametrize("value", [math.nan, math.inf, 1e308, -1e308])
def test_an_mvs_calibration_refuses_numbers_out_of_range(key, value, tmp_path):
    """droid-mvs --calib FILE and a cell's [subunits.X.calibration]: the same ranges."""
    from droid.subunits.mvs.sensor import load_calibration

    path = tmp_path / "calib.toml"
    path.write_text(dumps({key: value}))
    with pytest.raises(BadInput, match=rf"{key} = .*(finite|outside)") as exc:
        load_calibration(str(path))
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)


def _bad_copy(tmp_path, src: Path, path: tuple, value, name: str | None = None) -> Path:
    data = tomllib.loads(src.read_text())
    if name is not None:
        data["cell"]["name"] = name
        data["cell"]["run_dir"] = str(tmp_path / "run")
    out = tmp_path / src.name
    out.write_text(dumps(replaced(data, path, value)))
    return out


CLI = [  # (program, argv before the file, what the file is, path in it, value, words of the one line)
    ("droid-kin", ["fk", "0", "0", "0", "0", "0", "0", "--robot"], "kinematics/robots/reis_v15.toml",
     ("limits", "vmax_deg_s", 0), math.inf, ["limits.vmax_deg_s[0] = inf", "deg/s"]),
    ("droid-kin", ["fk", "0", "0", "0", "0", "0", "0", "--robot"], "kinematics/robots/fanuc_s400.toml",
     ("dynamics", "link_mass_kg", 2), -1e308, ["dynamics.link_mass_kg[2] = -1e+308", "kg"]),
    ("droid-experiment", ["list", "--plan"], "experiments/plans/sweep200.toml",
     ("sweep", "speed_mm_s", 0), math.nan, ["sweep.speed_mm_s[0] = nan"]),
    ("droid-sim", ["truth", "arm1", "--json", "--cell"], "cells/sim.toml",
     ("cell", "heartbeat_hz"), 1e308, ["cell.heartbeat_hz = 1e+308", "Hz"]),
    ("droid-sim", ["truth", "arm1", "--json", "--cell"], "cells/sim.toml",
     ("subunits", "gmf1", "base", 0), -math.inf, ["subunits.gmf1.base[0] = -inf", "mm"]),
]


@pytest.mark.parametrize("prog,argv,src,path,value,words", CLI,
                         ids=[f"{c[0]} {numbers.key_name(c[3])}={c[4]}" for c in CLI])
def test_programs_exit_2_with_one_line(prog, argv, src, path, value, words, tmp_path, cell_name):
    exe = Path(sys.executable).parent / prog
    if not exe.exists():
        pytest.skip(f"{prog} is not installed next to {sys.executable}")
    bad = _bad_copy(tmp_path, PKG / src, path, value, cell_name if src.startswith("cells/") else None)
    p = subprocess.run([str(exe), *argv, str(bad)], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1, p.stderr
    for w in words:
        assert w in lines[0], p.stderr
    assert str(bad) in lines[0] or bad.name in lines[0], p.stderr
    assert cell_objects(cell_name) == []


@pytest.mark.parametrize("prog,argv", [("droid-move", ["arm1", "joint", "0", "0", "0", "0", "0", "0", "2"]),
                                       ("droid-home", ["arm1"])])
def test_a_cell_with_a_bad_robot_file_exits_2_before_it_is_contacted(prog, argv, tmp_path, cell_name):
    """A subunit's robot given as a path to a robot file with nan in it: a task ends with one line
    and exit 2 (RobotFileError through droid.cli.run), not a traceback -- the cell (not up) is
    never asked (that would be exit 1)."""
    exe = Path(sys.executable).parent / prog
    if not exe.exists():
        pytest.skip(f"{prog} is not installed next to {sys.executable}")
    robot = _bad_copy(tmp_path, PKG / "kinematics/robots/reis_v15.toml", ("limits", "vmax_deg_s", 0), math.nan)
    cell = _bad_copy(tmp_path, PKG / "cells/sim.toml", ("subunits", "arm1", "robot"), str(robot), cell_name)
    p = subprocess.run([str(exe), *argv, "--cell", str(cell)], capture_output=True, text=True, timeout=60,
                       cwd=tmp_path, stdin=subprocess.DEVNULL)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "limits.vmax_deg_s[0] = nan" in lines[0] and str(robot) in lines[0], p.stderr
    assert cell_objects(cell_name) == []
