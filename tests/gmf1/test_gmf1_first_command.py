"""A command written before droid-gmf1-serial's first tick is executed, never acknowledged and lost.

Thesis Tables 3.1-3.2: a command (a new ``cmd_id``, ``sent``) is either executed or
refused, and Status says which (``cmd_id``, ``cmd_result``, ``busy``).  The serial program
used to take the Command record it found at its first tick as already handled, so a
droid-home written before that tick (in lockstep: before tick 0; in real time: right after
``droid-cell up``, before the program's relay subscription delivered its first tick) was
acknowledged by the agent (``sent`` cleared) and never sent to the KAREL server.

Virtual time only (lockstep): verdicts on behaviour, never on speed.
"""
from pathlib import Path

import numpy as np
import pytest

import droid

from droid.brain.db import arm_command
from droid.brain.db.layouts import CMD_OK, HOME_MODE, NORMAL_MODE
from droid.kinematics.transforms import T_to_pose, pose_to_T
from droid.sim.gmf1.lockstep import Gmf1Lockstep
from droid.subunits.gmf1.serial_core import SerialCore, SerialParams
from droid.subunits.gmf1.station import SerialStation

SIM_CELL = Path(droid.__file__).parent / "cells" / "sim.toml"
TARGET = [1060.51, -165.66, 2295.23, -170.0, 30.0, -160.0]  # global frame, reachable (test_gmf1_lockstep)


def homed_and_idle(g, cmd_id):
    s = g.status()
    return int(s["cmd_id"]) == cmd_id and int(s["busy"]) == 0 and int(s["homed"]) == 1


@pytest.mark.parametrize("ticks_before", [0, 1, 2])
def test_a_home_written_in_the_first_ticks_homes_the_arm(ticks_before):
    g = Gmf1Lockstep()
    g.run_ticks(ticks_before)
    cmd_id = g.command_home()  # as droid-home writes it (droid.brain.db.arm_command.home)
    assert g.run_until(lambda: homed_and_idle(g, cmd_id), 30), (
        f"sent {g.serial_core.sent}, dropped {g.serial_core.dropped}, last_seen {g.serial_core.last_seen}, "
        f"Status cmd_id {int(g.status()['cmd_id'])}")
    s = g.status()
    assert int(s["cmd_result"]) == CMD_OK and int(s["cmd_mode"]) == HOME_MODE
    assert int(g.brain_command.read()["sent"]) == 0  # acknowledged by the agent ... and done
    assert g.serial_core.sent == 1 and g.serial_core.dropped == 0 and g.controller.accepted >= 1
    np.testing.assert_allclose(g.controller.q_deg, 0, atol=1e-9)


def test_a_home_written_before_the_first_tick_then_a_move():
    """The home waits for the link (the first probe) and is done; the next move runs as usual."""
    g = Gmf1Lockstep()
    home_id = g.command_home()
    assert g.run_until(lambda: homed_and_idle(g, home_id), 30)
    arm_command.set_normal(g.brain_command)
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(1.0))
    assert g.run_until(lambda: g.done(cmd_id), 10)
    assert int(g.status()["cmd_result"]) == CMD_OK
    np.testing.assert_allclose(T_to_pose(g.true_pose_global()), TARGET, atol=1e-3)


def restart_serial(g):
    """droid-cell restart 'droid-gmf1-serial gmf1': a new program (core and station) on the same
    records and port; the old one is gone with whatever it held in memory."""
    g.link.close()
    core = SerialCore(g.model, g.serial_core.p)
    g.serial_core = core
    g.serial = SerialStation(core, g.link, g.ctrl_command, g.ctrl_status)
    return core


def test_a_restarted_serial_program_does_not_replay_what_it_answered():
    g = Gmf1Lockstep()
    g.run_ticks(2)
    assert g.home()
    home_id = g.home_id
    accepted = g.controller.accepted
    core = restart_serial(g)
    g.run_ticks(120)
    assert core.sent == 0 and g.controller.accepted == accepted
    assert int(g.status()["cmd_id"]) == home_id and int(g.status()["homed"]) == 1


def test_a_command_pending_when_the_serial_program_restarts_is_executed():
    g = Gmf1Lockstep()
    g.run_ticks(2)
    assert g.home()
    g.serial_running = False  # the program died; the agent still acknowledges
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(1.0))
    g.run_ticks(5)
    assert int(g.brain_command.read()["sent"]) == 0 and int(g.status()["cmd_id"]) != cmd_id
    restart_serial(g)
    g.serial_running = True
    assert g.run_until(lambda: g.done(cmd_id), 10)
    assert int(g.status()["cmd_result"]) == CMD_OK and int(g.status()["cmd_mode"]) == NORMAL_MODE
    np.testing.assert_allclose(T_to_pose(g.true_pose_global()), TARGET, atol=1e-3)


def test_the_whole_sim_cell_homes_the_gmf1_on_a_command_written_before_its_first_tick():
    """The same through droid.sim.lockstep_cell on droid/cells/sim.toml (droid-remote, the agent's
    copy and 'sent' acknowledgement, the relayed tick), as droid-home right after droid-cell up."""
    from droid.sim.lockstep_cell import build_lockstep_cell

    with build_lockstep_cell(SIM_CELL) as lc:
        sub = lc.subunits["gmf1"]
        cmd_id = arm_command.home(sub.command)
        for _ in range(30 * 60):
            lc.sched.run_ticks(1)
            st = sub.status.read()
            if int(st["cmd_id"]) == cmd_id and int(st["busy"]) == 0 and int(st["homed"]) == 1:
                break
        else:
            raise AssertionError(f"not homed: Status cmd_id {int(st['cmd_id'])}, homed {int(st['homed'])}")
        assert int(st["cmd_result"]) == CMD_OK and int(sub.command.read()["sent"]) == 0
