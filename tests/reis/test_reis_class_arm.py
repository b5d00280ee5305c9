"""A second Reis-class arm is one robot file plus a cell entry (issue 13), end to end in lockstep."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.db import layouts as L
from droid.cli import BadInput
from droid.sim.lockstep import Scheduler
from droid.sim.reis.cell import arms_from_cell

CELL = Path(__file__).resolve().parents[2] / "droid" / "cells" / "reis_pair.toml"


def test_both_arms_home_move_and_arrive_in_lockstep():
    cell = load_cell(str(CELL))
    s = Scheduler(60.0)
    arms = arms_from_cell(s, cell)
    assert set(arms) == {"arm1", "arm2"}
    a1, a2 = arms["arm1"], arms["arm2"]
    assert cell.stale_ticks != 3 and a1.stale_ticks == a2.stale_ticks == cell.stale_ticks  # the cell's, not the default
    # each arm's servo, planner and plant read its own file
    assert a2.servo_params.home_switch_deg == tuple(a2.model.home_switch_deg)
    assert a2.servo_params.home_switch_deg != a1.servo_params.home_switch_deg
    assert a2.model.name == "reis_class_b" and a2.plant.params.robot == "reis_class_b"
    assert not np.allclose(a2.servo_params.joint_to_counts, a1.servo_params.joint_to_counts)
    ids = {n: a.command_home() for n, a in arms.items()}
    done = a1.run_until(lambda: all(int(a.status["cmd_id"]) == ids[n] and int(a.status["homed"])
                                    and not int(a.status["busy"]) for n, a in arms.items()), 60.0)
    assert done
    for a in arms.values():
        a.set_normal()
    targets = {}
    for n, a in arms.items():
        T = a.model.fk([20.0, 10.0, 15.0, 5.0, 30.0, -10.0])
        targets[n] = T
        ids[n] = a.command_cart(T, a.ticks_for(2.0))
    assert a1.run_until(lambda: all(int(a.status["cmd_id"]) == ids[n] and not int(a.status["busy"])
                                    for n, a in arms.items()), 8.0)
    s.run_for(0.5)
    for n, a in arms.items():
        assert int(a.status["cmd_result"]) == L.CMD_OK
        # where its own controller believes it is (its encoders through its own gearing)
        believed = np.linalg.norm(a.wcp_from_counts(a.status["encoder_pos"])[:3, 3] - targets[n][:3, 3])
        assert believed < 0.2, (n, believed)
    # the truth: arm1's world matches its file; arm2's switches are off by home_error_deg
    # (0.2 deg on joint 2 alone moves the wrist centre ~4 mm), so it misses by millimetres
    err1 = np.linalg.norm(a1.wcp_global()[:3, 3] - targets["arm1"][:3, 3])
    err2 = np.linalg.norm(a2.wcp_global()[:3, 3] - targets["arm2"][:3, 3])
    assert err1 < 1.0, err1
    assert 2.0 < err2 < 20.0, err2
    t = a2.truth()
    assert len(t["q_deg"]) == 6 and len(t["wcp_mm"]) == 3 and json.dumps(t)


def test_a_world_naming_another_robot_file_is_refused_with_both_names(tmp_path):
    text = CELL.read_text().replace('robot = "reis_class_b"                          # must match',
                                    'robot = "reis_v15"  # must match')
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(BadInput) as exc:
        arms_from_cell(Scheduler(60.0), load_cell(str(p)))
    assert "reis_v15" in str(exc.value) and "reis_class_b" in str(exc.value)
