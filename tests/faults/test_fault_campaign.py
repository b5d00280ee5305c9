"""A short fault campaign (issue 8): random seeded faults during droid-move loops on a real
cell of processes; every count that must be zero is zero.  Recovery times are printed,
never asserted (bench/fault_campaign.py runs the long campaign)."""
from __future__ import annotations

import json

import pytest

from droid.faults.campaign import Campaign, Fault, MoveLoop, campaign_cell_text, plan

pytestmark = pytest.mark.integration


def test_plan_is_seeded_and_covers_every_kind():
    assert plan(30, 4) == plan(30, 4) and plan(30, 4) != plan(30, 5)
    kinds = {f.kind for f in plan(200, 1)}
    assert kinds == {"drop", "delay", "duplicate", "cut", "pause", "kill", "semkill"}


def test_a_task_program_is_a_workload_in_one_line():
    from droid.faults.campaign import CommandWorkload

    w = CommandWorkload("droid-move", lambda cell, i: ["droid.tasks.move", "--help"],
                        envelope=[[0] * 6, [1] * 6], recovery_target=[0] * 6)
    p = w.start("unused.toml", 0)
    assert p.wait(60) == 0
    p.stderr.close()
    assert w.envelope().shape == (2, 6) and w.recovery_target().shape == (6,)


def test_short_campaign_has_no_runaway_no_wedged_semaphore_and_no_leak(tmp_path, cell_name):
    path = tmp_path / f"{cell_name}.toml"
    path.write_text(campaign_cell_text(cell_name, str(tmp_path / "run")))
    faults = [  # one of each family, short, so the test stays short
        Fault("cut", "arm1", 0.0, 0.6, 0.4),
        Fault("pause", "droid-planner arm1", 0.0, 0.5, 0.5),
        Fault("kill", "droid-reis-agent arm1", 0.0, 0.5, 0.0),
        Fault("semkill", "arm1.ctrl_command", 0.0, 0.4, 0.0),
        Fault("drop", "arm1.agent", 0.5, 0.3, 0.8),
    ]
    result = Campaign(path, MoveLoop(), seed=3).run(faults)
    print(json.dumps({k: v for k, v in result.items() if k != "rounds"}, indent=1))
    assert result["faults"] == 5
    assert result["runaway"] == 0, result["rounds"]
    assert result["wedged"] == 0, result["rounds"]
    assert result["leaked"] == 0, result["leaked_items"]
    assert result["unrecovered"] == 0, result["rounds"]
    assert result["program_restarts"] >= 1  # the killed agent was brought back


def test_the_seam_tracking_workload_starts_at_the_layout_start_inside_its_envelope(tmp_path):
    """The campaign's second workload (issue 8: faults during seam tracking): its cell is the
    built-in seam-tracking cell with arm1's agent link behind the proxy; its recovery move
    goes to the seam start, and home and the start both lie inside its envelope."""
    import numpy as np

    from droid.brain.cell.cellfile import load_cell
    from droid.faults.campaign import WORKLOADS
    from droid.faults.cells import seam_campaign_cell_text
    from droid.kinematics import load_robot
    from droid.brain.cell.cell_layout import load_layout

    w = WORKLOADS["seamtrack"]()
    assert w.needs_holder
    lo, hi = w.envelope()
    start = w.recovery_target()
    assert np.all(lo <= 0) and np.all(hi >= 0) and np.all(lo <= start) and np.all(start <= hi)
    reis = load_robot("reis_v15")
    T, _ = load_layout().start_poses("i")
    assert np.allclose(reis.fk(reis.gearing.counts_to_joints(start.astype(float)))[:3, 3], T[:3, 3], atol=0.5)
    path = tmp_path / "c.toml"
    path.write_text(seam_campaign_cell_text("fcseam", str(tmp_path / "run")))
    cell = load_cell(path)
    assert {"arm1", "gmf1", "mvs", "tool"} <= set(cell.subunits)
    assert cell.bind_endpoint(cell.subunits["arm1"].agent).endswith("arm1.agent.inner")
