"""``droid-snoop guard`` on a cell whose live guard is off (issue 41; docs/guard.md §9).

A cell with ``[guard] run = false`` has the guard's Status database (droid-cell up makes it) and no
droid-guard: droid-snoop says so in one line, exit 0, and ``--json`` gives ``"state": "off"``.  No
cell is brought up: the answer is the cell file's.
"""
from __future__ import annotations

import json
import re

from droid.tasks import snoop

from tests.guard.test_cell import SIM


def _cell(tmp_path, run: str):
    text = SIM.read_text()
    text = re.sub(r"\nrun = (true|false)\n", "\n", text)  # whatever the shipped cell says
    text = text.replace("\n[guard]\n", f"\n[guard]\nrun = {run}\n", 1)
    path = tmp_path / f"guard_{run}.toml"
    path.write_text(text)
    return path


def test_the_guard_off_is_one_line_and_exit_0(tmp_path, capsys):
    cell = _cell(tmp_path, "false")
    assert snoop.main(["guard", "--cell", str(cell), "--count", "3"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 1, out
    assert out[0].startswith("guard: off in cell sim ([guard] run = false in ") and str(cell) in out[0]
    assert snoop.main(["guard", "--cell", str(cell), "--json"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert json.loads(line) == {"subunit": "guard", "cell": "sim", "state": "off", "run": False}


def test_a_cell_that_runs_the_guard_reads_its_status(tmp_path, capsys, monkeypatch):
    from droid.brain.db import layouts as L
    from droid.brain.db.shmdb import MemoryDatabase
    from droid.guard import live

    cell = _cell(tmp_path, "true")
    db = MemoryDatabase("guard.status", L.GUARD_STATUS_LAYOUT)
    db.update(tick=7, n_arms=2, distance_mm=120.5, separation_mm=35.0, state=L.GUARD_CLEAR)
    monkeypatch.setattr(live, "open_status", lambda c: db)
    assert snoop.main(["guard", "--cell", str(cell), "--count", "1", "--rate", "1000"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert line.startswith("guard tick 7  clear  120.5 mm: ") and "S_p 35.0 mm" in line
