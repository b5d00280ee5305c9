"""Integration: the MVS sensor and the tool-tip sensor in the running real-time cell.

The arms are fixed_arm twins: the Reis holds the sensor at start position (i)
of the seam-tracking layout; the holder is moved so that both sensors see the
step_input seam 3 mm to the left (+y).  droid-sim renders the camera and paces the
serial lines, droid-mvs extracts the feature, droid-remote mvs/tool read the
lines into the Brain's Status records, droid-snoop shows them.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from droid.brain.db.shmdb import cell_objects
from tests.brain.cellutil import ROOT, cell_status, droid, fixed_seam_cell, make_cell_file, wait_for

pytestmark = pytest.mark.integration
CELL = "droid.brain.runtime.launcher"
SNOOP = "droid.tasks.snoop"
LATERAL_MM = 3.0
#: Lateral tolerance of single readings [mm]: 0.2 mm rows, 0.5 px jitter and 2 % spurious
#: rows (docs/bench-mvs.md: worst single frame ~2.5 rows); the median must be within 0.25 mm.
SINGLE_TOL_MM = 0.6
MEDIAN_TOL_MM = 0.25


@pytest.fixture
def cell(tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name)
    path.write_text(fixed_seam_cell(path.read_text(), lateral_mm=LATERAL_MM))
    yield path
    out = droid(CELL, "down", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    assert cell_objects(cell_name) == []
    run = tmp_path / "run"
    assert not [p for p in os.listdir(run) if p != "logs"], os.listdir(run)  # no tty symlinks left


def up(path):
    out = droid(CELL, "up", "--cell", str(path), timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


def snoop(path, sub, count=1, rate=20):
    out = droid(SNOOP, sub, "--json", "--count", str(count), "--rate", str(rate), "--cell", str(path))
    assert out.returncode == 0, out.stderr
    return [json.loads(line) for line in out.stdout.splitlines()]


def fresh_valid(path, sub, count=1):
    recs = snoop(path, sub, count)
    return recs if all(not r["stale"] and not r["invalid"] for r in recs) else None


def test_sensor_reports_the_seam_under_a_stationary_arm(cell):
    up(cell)
    names = {r["name"] for r in cell_status(cell)}
    assert {"droid-mvs mvs", "droid-remote mvs", "droid-remote tool", "droid-sim"} <= names
    # the seam sensors have serial links, no agent (the generic droid-agent serves the joystick and the F/T sensor)
    assert not any(n in names for n in ("droid-agent mvs", "droid-agent tool"))
    wait_for(lambda: all(r["live"] for r in cell_status(cell)), what="every program live")
    recs = wait_for(lambda: fresh_valid(cell, "mvs", 10), what="ten fresh valid mvs readings")
    ys = [r["y"] for r in recs]
    assert abs(float(np.median(ys)) - LATERAL_MM) <= MEDIAN_TOL_MM, ys
    assert all(abs(y - LATERAL_MM) <= SINGLE_TOL_MM for y in ys), ys
    assert all(abs(r["x"]) <= 0.3 and r["z"] == 0.0 and r["fault"] == [] for r in recs)
    for r in recs:  # R = Rz(roll): a rotation about the sensor's z, roll ~ 0 over a flat joint
        R = np.array(r["R"])
        assert np.allclose(R[2], [0, 0, 1]) and np.allclose(R[:, 2], [0, 0, 1]) and abs(R[1, 0]) < 0.05
    counts = [r["valid_count"] for r in recs]
    assert counts == sorted(counts) and counts[-1] > counts[0]  # readings keep coming
    assert recs[-1]["tick"] > recs[0]["tick"]
    # the tool tip sits on the seam's height, 3 mm to its right: the geometry through the lead
    # sensor's noise model (the default cell's: sigmas 0.012 mm height, 0.056 mm lateral; 5 sigma)
    tool = wait_for(lambda: fresh_valid(cell, "tool", 3), what="fresh valid tool readings")
    for r in tool:
        assert r["x"] == pytest.approx(0.0, abs=0.06) and r["y"] == pytest.approx(LATERAL_MM, abs=0.3)
        assert r["garbled_count"] == 0 and r["invalid_count"] == 0
    plain = droid(SNOOP, "mvs", "--count", "1", "--cell", str(cell))
    assert plain.returncode == 0 and plain.stdout.startswith("mvs tick ") and "valid" in plain.stdout


def test_world_restart_the_links_go_stale_and_come_back(cell):
    up(cell)
    wait_for(lambda: fresh_valid(cell, "mvs") and fresh_valid(cell, "tool"), what="both sensors fresh")
    sim = next(r for r in cell_status(cell) if r["name"] == "droid-sim")
    os.kill(sim["pid"], signal.SIGKILL)  # the cables and the board vanish at once
    for sub in ("mvs", "tool"):
        rec = wait_for(lambda: (lambda r: r if r["stale"] else None)(snoop(cell, sub)[0]),
                       what=f"{sub} stale after the world died")
        assert {"link", "device"} <= set(rec["fault"]) and rec["invalid"]
    rows = {r["name"]: r for r in cell_status(cell)}
    assert rows["droid-remote mvs"]["alive"] and rows["droid-remote tool"]["alive"]
    assert rows["droid-mvs mvs"]["alive"]  # droid-mvs waits for its port and board to come back
    # the world comes back (by hand): the remotes reopen their ports, droid-mvs its port and board
    proc = subprocess.Popen([sys.executable, "-m", "droid.sim.world", "--cell", str(cell)], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: fresh_valid(cell, "tool"), timeout=30, what="tool fresh again")
        recs = wait_for(lambda: fresh_valid(cell, "mvs", 3), timeout=30, what="mvs fresh again")
        assert abs(float(np.median([r["y"] for r in recs])) - LATERAL_MM) <= MEDIAN_TOL_MM
    finally:
        proc.terminate()
        proc.wait(10)


# -- droid-mvs with --cell (no full cell: a stand-alone board and a pty end) -------------

def sensor_cell(tmp_path, cell_name, extra_mvs=""):
    path = make_cell_file(tmp_path, cell_name)
    text = path.read_text().replace('programs = ["droid-mvs"]', 'programs = ["droid-mvs"]\n' + extra_mvs)
    # these tests run droid-mvs's main() in the pytest process: not at FIFO priority
    # (tests/conftest.py, scheduler_leak)
    text = text.replace("sched_fifo = true", "sched_fifo = false", 1)
    path.write_text(text)
    return path


@pytest.mark.parametrize("argv,message", [
    (["arm1"], "[subunits.arm1] is class 'arm6r', not a line_laser sensor"),
    (["nosuch"], "unknown subunit 'nosuch'"),
    (["tool"], "[subunits.tool] needs dsp"),
    (["mvs", "--replay", "-"], "--replay takes no"),
])
def test_sensor_in_a_cell_bad_input_exit_2(tmp_path, cell_name, capsys, argv, message):
    from droid.subunits.mvs.sensor import main

    path = sensor_cell(tmp_path, cell_name)
    assert main(["--cell", str(path), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_sensor_in_a_cell_without_a_world_gives_up_with_a_reason(tmp_path, cell_name, capsys):
    from droid.subunits.mvs.sensor import main

    path = sensor_cell(tmp_path, cell_name, "board_wait = 0.3")
    assert main(["--cell", str(path), "mvs"]) == 1
    err = capsys.readouterr().err
    assert f"droid.{cell_name}.mvs.dsp" in err and "after waiting 0.3 s (is droid-sim running?)" in err
    # like every program, a failure leaves its presence record marked for droid-cell status
    from droid.brain.db.layouts import PROC_FAILED, PROC_STATUS_LAYOUT
    from droid.brain.db.shmdb import Database, db_name, unlink_database

    name = db_name(cell_name, "proc", "mvs-mvs")
    with Database(name, PROC_STATUS_LAYOUT) as db:
        rec = db.read()
    unlink_database(name)
    assert int(rec["state"]) == PROC_FAILED and rec["name"] == b"droid-mvs mvs"


def test_sensor_in_a_cell_takes_board_port_and_calibration_from_the_cell(tmp_path, cell_name):
    """droid-mvs --cell FILE mvs: dsp, sensor_serial and [subunits.mvs.calibration] from the file,
    the readiness handshake on --ready-fd, a presence record while it runs."""
    from droid.brain.plumbing.sensor_line import SensorClientCore
    from droid.sim.serial_cable import PtyEnd
    from droid.subunits.mvs.sensor import main

    # a calibration with twice the lateral scale doubles the y the sensor reports
    path = sensor_cell(tmp_path, cell_name, "[subunits.mvs.calibration]\nlateral_mm_per_row = 0.4\n")
    board = subprocess.Popen([sys.executable, "-m", "droid.sim.mvs.dsp", f"shm://droid.{cell_name}.mvs.dsp",
                              "--lateral", "2", "--jitter", "0.3"], cwd=ROOT, stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True)
    end = PtyEnd(str(tmp_path / "run" / "mvs.sensor.tty"))
    r, w = os.pipe()
    try:
        assert board.stdout.readline().strip() == "ready"
        assert main(["--cell", str(path), "mvs", "--count", "12", "--ready-fd", str(w)]) == 0
        assert os.read(r, 4) == b"R"
        client = SensorClientCore()
        data = b""
        deadline = time.monotonic() + 10
        while data.count(b"\n") < 12 and time.monotonic() < deadline:
            data += end.read()
            time.sleep(0.01)
        newest = client.feed(data)
        assert client.lines == 12 and client.valid >= 10
        assert newest.y_mm == pytest.approx(4.0, abs=0.5)
    finally:
        os.close(r)
        end.close()
        board.terminate()
        board.wait(10)
    assert cell_objects(cell_name) == []  # the presence record went away with a clean exit
