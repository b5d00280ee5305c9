"""droid-calibrate: the optical calibration of §4.1.1.4 recovers injected home errors (issue 13)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from droid.brain.cellfile import load_cell
from droid.sim.lockstep import Scheduler
from droid.sim.reis.cell import arms_from_cell
from droid.sim.reis.world import world_errors

CELL = Path(__file__).resolve().parents[2] / "droid" / "cells" / "reis_pair.toml"
#: Issue 13's target is 0.02 deg.  The estimate also carries the error of the homing it was
#: made under: on the compliant twin, joint 2's switch edge is caught with ~0.01-0.02 deg of
#: dynamic drive deflection (stick-slip of the 1-count fine approach; measured over seeds,
#: docs/reis.md), so the tests allow 0.03 deg; the V15 run in docs/reis.md met 0.006 deg.
TOL_DEG = 0.03


def _cell(tmp_path, name: str, world_table: str) -> Path:
    text = CELL.read_text().replace('name = "reispair"', f'name = "{name}"\nrun_dir = "{tmp_path}/run"')
    text = text.replace('home_error_deg = [0.0, 0.2, -0.15, 0.1, -0.3, 0.0]  # the world is not the model', world_table)
    p = tmp_path / "cell.toml"
    p.write_text(text)
    return p


def _calibrate(path, arm="arm2", *extra):
    return subprocess.run([sys.executable, "-m", "droid.sim.reis.calibrate", arm, "--cell", str(path), *extra],
                          capture_output=True, text=True, timeout=900)


def test_injected_home_errors_are_recovered_and_written_where_homing_uses_them(tmp_path, cell_name):
    injected = [0.0, 0.45, -0.35, 0.3, -0.5, 0.0]
    path = _cell(tmp_path, cell_name, f"home_error_deg = {injected}")
    r = _calibrate(path)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 1
    out = json.loads(lines[0])
    est = np.asarray(out["home_offset_deg"])
    assert est.shape == (6,)
    assert np.all(np.abs(est - injected) <= TOL_DEG), est - injected
    assert out["written"] and Path(out["written"]).is_file()
    # homing now uses them: a fresh lockstep cell reads the file; after homing the servo's
    # joint estimate matches the true links to the drives' deflection change (< 0.03 deg),
    # where the uncalibrated servo was off by the injected errors
    cell = load_cell(str(path))
    s = Scheduler(60.0)
    arm = arms_from_cell(s, cell)["arm2"]
    assert np.allclose(arm.home_offset_deg, est)
    assert arm.home()
    q_servo = arm.model.gearing.counts_to_joints(np.asarray(arm.status["encoder_pos"], float))
    assert np.all(np.abs(arm.plant.joint_deg - q_servo) < 0.03), arm.plant.joint_deg - q_servo


def test_calibration_seed_errors_are_recovered(tmp_path, cell_name):
    path = _cell(tmp_path, cell_name, "calibration_seed = 11\nlink_error_mm = [0, 0, 0, 0, 0, 0]\n"
                                      "twist_error_deg = [0, 0, 0, 0, 0, 0]")
    cell = load_cell(str(path))
    opts = cell.world["devices"]["arm2"]
    from droid.kinematics import load_robot

    injected, _ = world_errors("test", load_robot("reis_class_b"), opts)
    assert max(abs(v) for v in injected) > 0.1
    r = _calibrate(path, "arm2", "--no-write")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["written"] is None
    assert np.all(np.abs(np.asarray(out["home_offset_deg"]) - injected) <= TOL_DEG)


def test_bad_arguments_exit_2(tmp_path, cell_name):
    path = _cell(tmp_path, cell_name, "")
    r = _calibrate(path, "arm9")
    assert r.returncode == 2 and "arm9" in r.stderr and "Traceback" not in r.stderr
