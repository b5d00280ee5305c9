"""droid-calibrate: the optical calibration of §4.1.1.4 recovers injected home errors (issue 13)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from droid.brain.cell.cellfile import load_cell
from droid.sim.lockstep import Scheduler
from droid.sim.reis.cell import arms_from_cell
from droid.sim.reis.world import world_errors

CELL = Path(__file__).resolve().parents[2] / "droid" / "cells" / "reis_pair.toml"
#: Issue 13's target: injected offsets of up to 0.5 deg recovered within 0.02 deg.  (Measured
#: within 0.004 deg over seeds 1-8 on both arms, docs/reis.md, since homing brackets each switch
#: edge at rest and calibration reads each pose at rest.)
TOL_DEG = 0.02


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
    # joint estimate matches the true links to the drives' deflection change (< 0.03 deg: up to
    # ~0.02 deg between the edges' poses and the home pose, plus the estimate's error),
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


def _homing_error_deg(probe: bool, seed: int = 2) -> np.ndarray:
    """Home the compliant ``reis_class_b`` twin; per joint, the homed servo's joint angle against
    the true link at rest, less the injected switch errors and the static deflection change [deg]."""
    from droid.kinematics import load_robot
    from droid.sim.reis.calibrate import Predictor
    from droid.sim.reis.lockstep import make_reis_cell, run_homing
    from droid.sim.reis.plant import ReisPlantParams
    from droid.subunits.reis.servo_params import ServoParams

    injected = (0.0, 0.45, -0.35, 0.3, -0.5, 0.0)
    pp = ReisPlantParams(robot="reis_class_b", home_error_deg=injected)
    sp = ServoParams.from_robot("reis_class_b", **({} if probe else {"home_probe_resolution_counts": 0}))
    ls = make_reis_cell(seed=seed, plant_params=pp, servo_params=sp)
    ls.run(0.05)
    run_homing(ls)
    assert ls.servo.homed
    ls.run(1.5, record=False)  # at rest on the last edge
    model = load_robot("reis_class_b")
    pred = Predictor(model)
    edges = ls.servo.home_edge_joints_deg
    defl_edge = np.array([pred.deflection_deg(edges[i])[i] for i in range(6)])
    q_servo = model.gearing.counts_to_joints(np.asarray(ls.servo.encoder_pos, float))
    q = ls.plant.joint_deg
    return q - (q_servo + np.asarray(injected) + defl_edge - pred.deflection_deg(q))


def test_homing_brackets_the_switch_edges_at_rest_on_the_compliant_arm():
    """Homing's step 5: caught in motion (step 5 off) joint 2's edge carries the motor's lead over
    the ringing link, more than 0.01 deg on this seed; bracketed at rest every joint is within 0.005 deg."""
    assert np.max(np.abs(_homing_error_deg(probe=False))) > 0.01
    assert np.all(np.abs(_homing_error_deg(probe=True)) < 0.005)
