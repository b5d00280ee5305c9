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
