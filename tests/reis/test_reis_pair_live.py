"""Two Reis-class arms in the real-time process cell (issue 13): each arm's programs and its
plant twin read its own robot file; the world shows its truth; a robot-file mismatch between
controller and world is refused at ``droid-cell up``.  Integration tests: the coordinator runs
them (live cells); lockstep twins of these checks are in test_reis_class_arm.py."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from droid.brain.db.shmdb import cell_objects
from droid.kinematics import load_robot
from tests.brain.cellutil import droid, home_at_once, make_cell_file

pytestmark = pytest.mark.integration
PAIR = Path(__file__).resolve().parents[2] / "droid" / "cells" / "reis_pair.toml"


def test_both_arms_home_move_and_the_world_tells_the_truth(tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name, source=PAIR)
    out = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=180)
    try:
        assert out.returncode == 0, out.stdout + out.stderr
        goal_deg = [20, 10, 15, 5, 30, -10]
        home_at_once(path, ("arm1", "arm2"))  # both Reis servos search their switches at once
        for arm, robot in (("arm1", "reis_v15"), ("arm2", "reis_class_b")):
            counts = load_robot(robot).gearing.joints_to_counts_int(np.asarray(goal_deg, float))
            droid("droid.tasks.move", arm, "joint", *(str(int(c)) for c in counts), "3", "--cell", str(path),
                  timeout=60, check=True)  # droid-move's joint targets are encoder counts
        t = droid("droid.sim.world", "truth", "arm2", "--json", "--cell", str(path))
        assert t.returncode == 0, t.stderr
        truth = json.loads(t.stdout)
        # arm2's switches are off by the cell's home_error_deg: the true angles differ from the
        # commanded ones by about that (plus the drives' deflection, < 0.3 deg)
        err = np.asarray(truth["q_deg"]) - goal_deg
        assert np.all(np.abs(err - [0.0, 0.2, -0.15, 0.1, -0.3, 0.0]) < 0.35), err
        assert len(truth["wcp_mm"]) == 3
    finally:
        down = droid("droid.brain.runtime.launcher", "down", "--cell", str(path), timeout=120)
        assert down.returncode == 0, down.stderr
        assert cell_objects(cell_name) == []


def test_controller_and_world_naming_different_robot_files_is_refused_at_up(tmp_path, cell_name):
    text = PAIR.read_text().replace('robot = "reis_class_b"                          # must match',
                                    'robot = "reis_v15"  # must match')
    src = tmp_path / "bad_src.toml"
    src.write_text(text)
    path = make_cell_file(tmp_path, cell_name, source=src)
    out = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=180)
    try:
        assert out.returncode != 0
        assert "reis_v15" in out.stderr and "reis_class_b" in out.stderr, out.stderr
    finally:
        droid("droid.brain.runtime.launcher", "down", "--cell", str(path), timeout=120)
        assert cell_objects(cell_name) == []
