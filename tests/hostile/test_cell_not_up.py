"""Every program of a subunit, started on a cell that is not up (docs/design.md §6, "Bad input").

Each must end at once with exit 1 and one line on stderr that says what it could not find,
and leave nothing of the cell in /dev/shm (the ``no_leaks`` fixture checks; session 17 found
droid-watchdog leaving its presence record, made before the database it then failed to open).
droid-mvs is not here: it waits OPEN_WAIT_S for its DSP board before it gives up, and its
failed start leaves its presence record marked failed for ``droid-cell status`` (removed by
``droid-cell down``), by design (droid.brain.runtime.program.Presence.close).
"""
from __future__ import annotations

import subprocess
import sys

import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.cell.registry import program
from droid.brain.db.shmdb import cell_objects
from droid.brain.cell.cellfile import builtin_cell_path
from tests.brain.cellutil import make_cell_file

WAITS_FOR_ITS_DEVICE = {"droid-mvs"}
CASES = sorted({(p, s.name) for s in load_cell(builtin_cell_path()).subunits.values()
                for p in s.programs if p not in WAITS_FOR_ITS_DEVICE})


def test_the_default_cell_has_programs_to_try():
    assert len(CASES) >= 10 and ("droid-watchdog", "arm1") in CASES


@pytest.mark.parametrize("prog, sub", CASES, ids=[f"{p} {s}" for p, s in CASES])
def test_a_program_on_a_cell_not_up_exits_1_with_one_line_and_leaves_nothing(prog, sub, tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name)
    out = subprocess.run([sys.executable, "-m", program(prog).module, sub, "--cell", str(path)],
                         capture_output=True, text=True, timeout=60)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 1, out.stderr
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: "), out.stderr
    assert "Traceback" not in out.stderr
    assert cell_objects(cell_name) == []
