"""A JOG after homing moves by its relative counts (thesis §3.4), wherever the arm stands.

The planner used to write the arm's absolute position into ``encoder_cmd_ext`` in every
non-NORMAL mode, over the Brain's relative JOG counts the agent had copied there: the servo
agent then added the position to its goal.  Near home (0 counts) that went unseen (a Reis jog
of +100 counts at 20000 counts went to +138); on the ABB, whose home is not at 0 counts, one
jog drove every joint to its limit.  Found 2026-11-27 (issue 26)."""
from __future__ import annotations

import numpy as np

from droid.brain.db import arm_command
from droid.sim.lockstep import Scheduler
from droid.sim.reis.cell import LockstepArm


def test_a_jog_away_from_home_moves_by_its_counts_only():
    sched = Scheduler(60.0)
    arm = LockstepArm(sched, "arm1", seed=3)
    assert arm.home(60.0)
    start = np.array([20000, -8000, 6000, 0, 0, 0])
    assert arm.move_done(arm.command_joint(start, arm.ticks_for(3.0)), 10.0)
    sched.run_for(1.0)
    delta = np.array([100, 0, -50, 0, 0, 0])
    cmd_id = arm_command.jog(arm.brain_command, delta)
    sched.run_for(2.0)
    st = arm.status
    assert int(st["cmd_id"]) == cmd_id
    assert np.array_equal(np.asarray(st["encoder_cmd"]), start + delta), st["encoder_cmd"]
    assert np.max(np.abs(np.asarray(st["encoder_pos"]) - (start + delta))) <= 2, st["encoder_pos"]
