"""droid-contact on the real-time process cell (issue 27 item 5; thesis §7.3): the default cell's
Reis presses its nozzle on the step workpiece the GMF1 holds, through droid-sim's contact
device, read by droid-ft from the Net F/T twin.

On the session's shared homed cell (tests/conftest.py ``homed_sim_cell``; its fixture
proves nothing stays).  No timing decides a verdict: the tolerances are stated below and
the waits are generous.
"""
from __future__ import annotations

import csv
import time

import numpy as np
import pytest

from tests.brain.cellutil import droid, wait_for
from tests.tasks.test_seamtrack_cell import snoop

pytestmark = pytest.mark.integration
CONTACT = "droid.tasks.contact.prog"
#: Stated tolerance on the real-time cell: the mean normal force over the path after settling
#: within this of the setpoint, and no reading beyond the over-force limit [N].  (The issue's
#: target -- RMS <= 1 N, peak <= 3 N -- is a benchmark figure, docs/benchmarks.md, not a verdict
#: here: a loaded host stretches the loop.)
MEAN_FORCE_TOL_N = 3.0


def read_rows(path):
    from droid.tasks.contact.report import COLUMNS

    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == COLUMNS
    return [dict(zip(COLUMNS, r)) for r in rows[1:]]


def assert_standing(cell):
    """No motion commanded (the servo's command constant, not busy) and the arm still.  Pressed on
    the surface the servo settles for up to ~0.5 s after its stop (the halt record's settled_tick):
    that is waited for (a wait, not a verdict), then the command must not change."""
    def still():
        x = snoop(cell, "arm1")["encoder_pos"]
        time.sleep(0.5)
        return np.max(np.abs(np.subtract(x, snoop(cell, "arm1")["encoder_pos"]))) <= 2

    wait_for(still, timeout=20, what="the arm settled")
    a = snoop(cell, "arm1")
    time.sleep(0.5)
    b = snoop(cell, "arm1")
    assert b["busy"] == 0 and a["encoder_cmd"] == b["encoder_cmd"], (a, b)
    assert np.max(np.abs(np.subtract(a["encoder_pos"], b["encoder_pos"]))) <= 2, (a, b)


def test_droid_contact_presses_slides_and_stops_on_over_force(homed_sim_cell, tmp_path):
    sim_cell = homed_sim_cell
    log, fig = tmp_path / "f.csv", tmp_path / "f.png"
    out = droid(CONTACT, "arm1", "--start", "i", "--force", "20", "--speed", "10", "--length", "40",
                "--log", str(log), "--figure", str(fig), "--cell", str(sim_cell), timeout=240)
    assert out.returncode == 0, out.stderr
    assert "stopped: end" in out.stderr
    line = out.stdout.splitlines()[0]
    assert line.startswith("normal force RMS error ") and "stop: end" in line, line
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = read_rows(log)
    phases = [r["phase"] for r in rows]
    assert phases[0] == "approach" and "settle" in phases and phases[-1] == "path"
    path = [r for r in rows if r["phase"] == "path"]
    t_from = float(path[0]["t_s"]) + 1.0
    settled = np.array([float(r["force_n"]) for r in path if float(r["t_s"]) >= t_from])
    assert len(settled) >= 30  # 40 mm at 10 mm/s, 30 Hz cycles, less the settling second
    assert abs(float(np.mean(settled)) - 20.0) <= MEAN_FORCE_TOL_N, settled
    assert np.all(settled < 60.0)
    along = np.array([float(r["along_mm"]) for r in path])
    assert 35.0 <= along[-1] <= 45.0 and along[-1] > along[0]
    assert_standing(sim_cell)
    ft = snoop(sim_cell, "ft")
    assert ft["valid"] == 1 and ft["dropped"] >= 0

    # over-force: gains whose touch threshold lies above the over-force limit -- the approach
    # presses on until the station stops it; one line, exit 1, no motion left
    gains = tmp_path / "press.toml"
    gains.write_text("touch_n = 45.0\nforce_max_n = 40.0\n")
    out = droid(CONTACT, "arm1", "--start", "i", "--force", "20", "--gains", str(gains), "--log",
                str(tmp_path / "o.csv"), "--cell", str(sim_cell), timeout=240)
    assert out.returncode == 1, out.stderr
    assert "stopped: over-force (normal force" in out.stderr and "Traceback" not in out.stderr, out.stderr
    assert "stop: over-force" in out.stdout
    assert_standing(sim_cell)
