"""The neutral arm's ``Arm`` protocol (issue 43 item 1; droid.arm.protocol): what a task drives of an
arm, satisfied by ``BrainArm`` in real time and by the ``arm`` of every lockstep builder -- the Reis's,
the GMF1's and the ABB's -- with one meaning for ``home``: True when homed, False when not in time
(never a cmd_id, never an exception).  Only virtual time decides a verdict here."""
from __future__ import annotations

import ast
from pathlib import Path

from droid.arm.protocol import Arm
from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.sim.lockstep_cell import build_lockstep_cell
from droid.tasks.arm import BrainArm

MEMBERS = ("name", "read", "command_home", "command_joint", "command_cart", "ticks_for", "set_normal", "home",
           "move_done")


def test_the_protocol_names_what_a_task_drives_and_imports_nothing_of_droid():
    assert {m for m in vars(Arm) if not m.startswith("_")} >= set(MEMBERS)
    tree = ast.parse(Path(__import__("droid.arm.protocol", fromlist=["x"]).__file__).read_text())
    mods = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    mods += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    assert not [m for m in mods if m and m.startswith("droid")]


def test_brain_arm_is_an_arm():
    arm = BrainArm(load_cell(BUNDLED_CELLS / "sim.toml"), "arm1")  # not connected: the interface only
    assert isinstance(arm, Arm) and arm.name == "arm1"


def test_every_lockstep_builders_arm_is_an_arm_and_homes_with_a_bool():
    with build_lockstep_cell(BUNDLED_CELLS / "sim.toml") as lc:
        arms = {n: s.arm for n, s in lc.subunits.items() if s.arm is not None}
        assert set(arms) == {"arm1", "gmf1"}
        for name, arm in arms.items():
            assert isinstance(arm, Arm) and arm.name == name
        assert arms["arm1"].home(0.05) is False  # the Reis searches its switches for seconds
        lc.run_for(1.0)
        for name, arm in arms.items():
            assert arm.home(60.0) is True, name
            st = arm.read()
            assert int(st["homed"]) == 1 and int(st["busy"]) == 0, name
    with build_lockstep_cell(BUNDLED_CELLS / "abb_weld.toml") as lc:
        abb = lc.subunits["abb"].arm
        assert isinstance(abb, Arm) and abb.name == "abb"
        assert abb.home(5.0) is True


def test_the_gmf1_lockstep_homes_with_a_bool_as_the_arm_chain_does():
    from droid.sim.gmf1.lockstep import Gmf1Lockstep

    g = Gmf1Lockstep()
    g.run_ticks(2)
    g.serial_running = False  # no KAREL line: the controller never hears HOME
    assert g.home(0.5) is False
    g.serial_running = True
    assert g.home(30.0) is True and int(g.status()["cmd_id"]) == g.home_id
