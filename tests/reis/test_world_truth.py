"""The world's truth through its own door: droid-sim truth ARM --json (issue 13)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.cli import BadInput
from droid.sim.world import build_world

CELL = Path(__file__).resolve().parents[2] / "droid" / "cells" / "reis_pair.toml"


def _cell(tmp_path, name, replace=None):
    text = CELL.read_text().replace('name = "reispair"', f'name = "{name}"')
    if replace:
        text = text.replace(*replace)
    p = tmp_path / "cell.toml"
    p.write_text(text)
    return p


def _truth(path, arm):
    return subprocess.run([sys.executable, "-m", "droid.sim.world", "truth", arm, "--json", "--cell", str(path)],
                          capture_output=True, text=True, timeout=60)


def test_truth_prints_the_true_joint_angles_and_wrist_centre(tmp_path, cell_name):
    path = _cell(tmp_path, cell_name)
    r = _truth(path, "arm2")
    assert r.returncode == 1 and "not running" in r.stderr  # no world yet
    world = build_world(load_cell(str(path)))
    try:
        for _ in range(50):
            world.advance(0.001)
        dev = world.devices["arm2"]
        r = _truth(path, "arm2")
        assert r.returncode == 0, r.stderr
        lines = r.stdout.strip().splitlines()
        assert len(lines) == 1
        t = json.loads(lines[0])
        assert t["arm"] == "arm2" and len(t["q_deg"]) == 6 and len(t["wcp_mm"]) == 3
        assert np.allclose(t["q_deg"], dev.plant.joint_deg, atol=1e-9)
        assert np.allclose(t["wcp_mm"], dev.wcp_global()[:3, 3], atol=1e-9)
        # the global frame: arm2 stands at x = 2500 mm, turned 180 deg
        assert t["wcp_mm"][0] > 1000.0
        # the true switches are the robot file's plus the cell's home_error_deg
        assert np.allclose(np.asarray(dev.plant.params.switch_joint_deg) - dev.plant.params.model.home_switch_deg,
                           [0.0, 0.2, -0.15, 0.1, -0.3, 0.0])
        assert _truth(path, "arm9").returncode == 2
    finally:
        world.close()


def test_calibration_seed_draws_documented_errors(tmp_path, cell_name):
    path = _cell(tmp_path, cell_name, ('home_error_deg = [0.0, 0.2, -0.15, 0.1, -0.3, 0.0]', 'calibration_seed = 4'))
    world = build_world(load_cell(str(path)))
    try:
        p = world.devices["arm2"].plant.params
        err = np.asarray(p.switch_joint_deg) - p.model.home_switch_deg
        assert err[0] == 0.0 and err[5] == 0.0  # joints 1 and 6: arbitrary zeros (§4.1.1.4)
        assert np.all(np.abs(err[1:5]) <= 0.5) and np.any(err[1:5] != 0.0)
        assert not p.dh_error.zero
    finally:
        world.close()


def test_a_world_device_naming_another_robot_file_is_refused(tmp_path, cell_name):
    path = _cell(tmp_path, cell_name, ('robot = "reis_class_b"                          # must match',
                                       'robot = "reis_v15"  # must match'))
    with pytest.raises(BadInput) as exc:
        build_world(load_cell(str(path)))
    assert "reis_v15" in str(exc.value) and "reis_class_b" in str(exc.value)
