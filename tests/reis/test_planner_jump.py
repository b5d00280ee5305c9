"""droid-planner's jump check (droid.arm.planner.JumpCheck): a way-point that steps farther in one
tick than half the robot file's joint speed limit allows is logged with the command it came from,
once a command; steps within it are not."""
from __future__ import annotations

import numpy as np

from droid.arm.planner import JumpCheck, PlanOutput
from droid.brain.cell.cellfile import builtin_cell_path, load_cell
from droid.brain.db.layouts import CTRL_COMMAND, JSPACE
from droid.kinematics import load_robot


def _out(counts) -> PlanOutput:
    out = PlanOutput()
    out.encoder_cmd_int = np.asarray(counts, np.int32)
    out.plan_ext = np.asarray(counts, np.int32) + 5
    return out


def test_a_step_over_the_joint_speed_limit_is_logged_with_its_command():
    cell = load_cell(builtin_cell_path())
    model = load_robot(cell.subunit("arm1").robot)
    check = JumpCheck(model, cell.heartbeat_hz)
    per_tick = np.abs(model.gearing.joint_to_counts_matrix) @ np.asarray(model.vmax_deg_s, float) \
        / cell.heartbeat_hz * 0.5
    assert np.allclose(check.limit, per_tick)
    cmd = np.zeros((), CTRL_COMMAND)
    cmd["cmd_id"], cmd["coord"], cmd["cart_time_count"], cmd["x"], cmd["R"] = 635, JSPACE + 1, 2, 812.5, np.eye(3)
    start = np.array([100, -200, 300, 0, 50, -60])
    assert check.note(_out(start), cmd) == ""  # the first way-point: nothing to compare
    within = start + np.floor(per_tick).astype(int)  # every joint at its limit: not a jump
    assert check.note(_out(within), cmd) == ""
    over = within.copy()
    over[5] += int(per_tick[5]) + 2
    line = check.note(_out(over), cmd)
    assert line.startswith("way-point step over half the joint speed limit: joint 6 ")
    assert "command 635 (cartesian, 2 ticks, pose x 812.50" in line and "1 so far" in line
    assert f"{within.tolist()} -> {over.tolist()}" in line
    assert check.note(_out(over), cmd) == ""  # standing again
    again = over.copy()
    again[5] += int(per_tick[5]) + 2
    assert check.note(_out(again), cmd) == ""  # the same command again: one line a command
    over = again
    cmd["cmd_id"], cmd["coord"], cmd["joint_time_count"] = 636, JSPACE, 3
    back = over - np.array([0, 3 * int(per_tick[1]), 0, 0, 0, 0])
    line = check.note(_out(back), cmd)
    assert "joint 2 " in line and "command 636 (joint, 3 ticks, counts " in line and "3 so far" in line
