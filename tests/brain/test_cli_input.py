"""Bad input to the foundation's programs: one line on stderr, exit 2, nothing started."""
from __future__ import annotations

import re

import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.db.shmdb import cell_objects
from tests.brain.cellutil import droid, make_cell_file
from tests.refusals import refused


@pytest.mark.parametrize("text,msg", [
    ("", "missing 'cell'"),
    ("[cell\nname=1", "not valid TOML"),
    ('[cell]\nname = "a.b"\n[subunits.x]\nclass="arm6r"\nrobot="reis_v15"', "invalid cell name"),
    ('[cell]\nname = "c"\n', "missing 'subunits'"),
    ('[cell]\nname = "c"\nheartbeat_hz = -5\n[subunits.x]\nclass="line_laser"', "heartbeat_hz"),
    ('[cell]\nname = "c"\nheartbeat_hz = 1e-320\n[subunits.x]\nclass="line_laser"', r"outside \[1, 1000\] Hz"),
    ('[cell]\nname = "c"\nheartbeat_hz = 1000.5\n[subunits.x]\nclass="line_laser"', r"outside \[1, 1000\] Hz"),
    ('[cell]\nname = "c"\nbogus = 1\n[subunits.x]\nclass="line_laser"', "unknown key"),
    ('[cell]\nname = "c"\n[subunits.x]\nclass="hexapod"', "unknown class"),
    ('[cell]\nname = "c"\n[subunits.x]\nclass="arm6r"', "needs 'robot'"),
    ('[cell]\nname = "c"\n[subunits.x]\nclass="line_laser"\nagent="http://x"', "endpoint"),
    ('[cell]\nname = "c"\n[subunits.x]\nclass="arm6r"\nrobot="r"\nbase=[1,2,3]', "6 finite numbers"),
    ('[cell]\nname = "c"\n[subunits.x]\nclass="line_laser"\nprograms=["droid-nope"]', "unknown program"),
])
def test_bad_cell_files(tmp_path, text, msg):
    assert re.search(msg, refused(tmp_path / "bad.toml", text, load_cell))


@pytest.mark.parametrize("args,msg", [
    (["up", "--cell", "/nonexistent/cell.toml"], "not found"),
    (["up", "--timeout", "nan"], "not a finite number"),
    (["frobnicate"], "invalid choice"),
    (["up", "--host", "mars"], "unknown host"),
])
def test_launcher_bad_args(args, msg, tmp_path, cell_name):
    if "--cell" not in args:
        args = args + ["--cell", str(make_cell_file(tmp_path, cell_name))]
    out = droid("droid.brain.runtime.launcher", *args)
    assert out.returncode == 2, out.stderr
    assert msg in out.stderr and len(out.stderr.strip().splitlines()) == 1
    assert cell_objects(cell_name) == []


@pytest.mark.parametrize("args,msg", [
    (["nosuch"], "unknown subunit"),
    (["arm1", "--rate", "0"], "must be >= 0.001 and <= 1000 Hz"),
    (["arm1", "--rate", "inf"], "not a finite number"),
    (["arm1", "--count", "x"], "not an integer"),
    ([], "the following arguments are required"),
])
def test_snoop_bad_args(args, msg, tmp_path, cell_name):
    out = droid("droid.tasks.snoop", *args, "--cell", str(make_cell_file(tmp_path, cell_name)))
    assert out.returncode == 2, out.stderr
    assert msg in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_help_everywhere():
    import subprocess
    import sys

    from droid.programs import PROGRAMS
    from tests.brain.cellutil import ROOT

    procs = {prog: subprocess.Popen([sys.executable, "-m", module, "--help"], cwd=ROOT, text=True,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for prog, module in PROGRAMS.items()}
    for prog, p in procs.items():
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0 and "usage:" in out, (prog, err)


def test_pyproject_scripts_match_program_table():
    import tomllib
    from pathlib import Path

    from droid.programs import PROGRAMS

    data = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    assert data["project"]["scripts"] == {k: f"{v}:main" for k, v in PROGRAMS.items()}
