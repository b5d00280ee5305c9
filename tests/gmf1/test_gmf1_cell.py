"""Integration: the real process cell with the GMF1 programs, driven by droid-home / droid-move.

Generous waits, no timing verdicts.  Each test brings its own uniquely named cell up and always
brings it down.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.db.databases import open_brain
from droid.brain.db.shmdb import pid_alive
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T, T_to_pose
from tests.brain.cellutil import ROOT, brought_down, cell_status, droid, make_cell_file, wait_for

pytestmark = pytest.mark.integration
CELL = "droid.brain.runtime.launcher"
SNOOP = "droid.tasks.snoop"
MODEL = load_robot("fanuc_s400").with_base(pose_to_T(2000, 0, 0, 180, 0, 0))
TARGET = [round(v, 3) for v in T_to_pose(MODEL.fk([0, 10, 10, 0, 40, 20]))]


@pytest.fixture
def cell(tmp_path, cell_name):
    with brought_down(make_cell_file(tmp_path, cell_name), cell_name) as path:
        yield path


def snoop(path):
    out = droid(SNOOP, "gmf1", "--json", "--count", "1", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.splitlines()[0])


def test_home_and_cartesian_move_in_the_real_cell(cell):
    out = droid(CELL, "up", "--cell", str(cell), timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    names = {r["name"] for r in cell_status(cell)}
    assert {"droid-gmf1-agent gmf1", "droid-gmf1-serial gmf1", "droid-gmf1-encoder gmf1"} <= names
    first = wait_for(lambda: (lambda s: s if not s["stale"] and not s["fault"] else None)(snoop(cell)),
                     timeout=30, what="gmf1 fresh and without faults")
    assert first["homed"] == 0
    # a cartesian move before homing is refused by droid-move (exit 1), nothing moves
    before = snoop(cell)["encoder_pos"]
    out = droid("droid.tasks.move", "gmf1", "cart", *map(str, TARGET), "2", "--cell", str(cell))
    assert out.returncode == 1 and "not homed" in out.stderr
    assert snoop(cell)["encoder_pos"] == before
    out = droid("droid.tasks.home", "gmf1", "--timeout", "60", "--cell", str(cell), timeout=90)
    assert out.returncode == 0, out.stderr
    s = snoop(cell)
    assert s["homed"] == 1 and all(abs(v) <= 1 for v in s["encoder_pos"])
    out = droid("droid.tasks.move", "gmf1", "cart", *map(str, TARGET), "2", "--cell", str(cell), timeout=90)
    assert out.returncode == 0, out.stderr
    s = wait_for(lambda: (lambda r: r if abs(r["x"] - TARGET[0]) < 0.5 and abs(r["y"] - TARGET[1]) < 0.5
                          and abs(r["z"] - TARGET[2]) < 0.5 else None)(snoop(cell)),
                 timeout=30, what="gmf1 Status at the target")
    assert s["busy"] == 0 and s["fault"] == [] and s["cmd_mode"] == "NORMAL"
    R = np.array(s["R"])
    np.testing.assert_allclose(R, pose_to_T(*TARGET)[:3, :3], atol=1e-3)
    # the world going away is a device fault on gmf1, not a crash of its programs
    sim = next(r for r in cell_status(cell) if r["name"] == "droid-sim")
    os.kill(sim["pid"], signal.SIGTERM)
    wait_for(lambda: "device" in snoop(cell)["fault"], timeout=30, what="gmf1 device fault")
    rows = {r["name"]: r for r in cell_status(cell)}
    assert rows["droid-gmf1-serial gmf1"]["live"] and rows["droid-gmf1-encoder gmf1"]["live"]


def test_a_home_acknowledged_while_the_serial_program_is_dead_is_done_after_its_restart(cell):
    """Tables 3.1-3.2: a command is executed or refused, never lost.  droid-home's command reaches
    the agent ('sent' cleared) while droid-gmf1-serial is dead; 'droid-cell restart' brings the
    program back and the arm homes.  (Its first tick used to take the command found as handled:
    droid-home waited until its time-out.  The same rule lost a droid-home written right after
    droid-cell up, before the program's first relayed tick: tests/gmf1/test_gmf1_first_command.py.)"""
    out = droid(CELL, "up", "--cell", str(cell), timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    wait_for(lambda: (lambda s: not s["stale"] and not s["fault"])(snoop(cell)), timeout=30,
             what="gmf1 fresh and without faults")
    serial = next(r for r in cell_status(cell) if r["name"] == "droid-gmf1-serial gmf1")
    os.kill(serial["pid"], signal.SIGKILL)
    wait_for(lambda: not pid_alive(serial["pid"]), timeout=30, what="droid-gmf1-serial gone")
    c = load_cell(cell)
    command = open_brain(c, c.subunit("gmf1"), "command")
    home = subprocess.Popen([sys.executable, "-m", "droid.tasks.home", "gmf1", "--timeout", "90", "--cell", str(cell)],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (lambda r: int(r["cmd_id"]) != 0 and int(r["sent"]) == 0)(command.read()), timeout=60,
                 what="droid-home's command acknowledged by the agent")
        assert int(snoop(cell)["homed"]) == 0
        out = droid(CELL, "restart", "droid-gmf1-serial gmf1", "--cell", str(cell), timeout=60)
        assert out.returncode == 0, out.stdout + out.stderr
        _, err = home.communicate(timeout=120)
        assert home.returncode == 0, err
    finally:
        command.close()
        if home.poll() is None:
            home.kill()
            home.wait(10)
    s = snoop(cell)
    assert s["homed"] == 1 and all(abs(v) <= 1 for v in s["encoder_pos"])


@pytest.mark.parametrize("prog", ["droid.subunits.gmf1.serial_prog", "droid.subunits.gmf1.encoder_prog"])
def test_programs_refuse_bad_cell_keys_in_one_line(tmp_path, cell_name, prog):
    path = make_cell_file(tmp_path, cell_name)
    text = path.read_text().replace('encoder_hz = 120.0', 'encoder_hz = 120.0\nencoders_typo = 1')
    path.write_text(text)
    out = droid(prog, "gmf1", "--cell", str(path))
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "encoders_typo" in out.stderr


def test_programs_without_a_cell_fail_cleanly(tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name)
    for prog in ("droid.subunits.gmf1.serial_prog", "droid.subunits.gmf1.encoder_prog"):
        out = droid(prog, "gmf1", "--cell", str(path))
        assert out.returncode == 1 and "is the cell up" in out.stderr
        assert "Traceback" not in out.stderr
