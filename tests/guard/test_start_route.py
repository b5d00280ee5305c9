"""droid-seamtrack's and droid-contact's start moves go around the welder (issue 41; docs/guard.md §9).

On the shipped cells the holder's straight move from home to the holding pose of (i) sweeps its
workpiece through the welder's forearm standing at home: :func:`droid.tasks.seamtrack.start_route`
finds it with the guard's bodies and takes the detour (both legs checked), the welder's move to
the start against the holder at its holding pose goes straight, and a start that neither way
clears is refused with the guard's line.  The other arm is faked where it stands
(droid.tasks.guarded._other_arm), as the Brain Status would give it.
"""
from __future__ import annotations

import numpy as np
import pytest

from droid.brain.cell.cell_layout import layout_for_cell
from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.cli import BadInput
from droid.kinematics import load_robot
from droid.tasks import guarded, seamtrack
from droid.tasks.arm import BrainArm


def _setup(name: str, monkeypatch, where: dict):
    cell = load_cell(BUNDLED_CELLS / name)
    layout = layout_for_cell(cell)
    homes = {n: np.asarray(load_robot(cell.subunit(n).robot).home_switch_deg, float)
             for n in (layout.tool_robot, layout.holder_robot)}
    monkeypatch.setattr(guarded, "_other_arm", lambda cell, n, gearing: (where.get(n, homes[n]), None, False))
    return cell, layout, homes


@pytest.mark.parametrize("name", ["sim.toml", "abb_weld.toml"])
def test_the_holder_goes_around_the_welder_and_the_welder_straight_to_the_start(name, monkeypatch):
    where: dict = {}
    cell, layout, homes = _setup(name, monkeypatch, where)
    welder, holder = BrainArm(cell, layout.tool_robot), BrainArm(cell, layout.holder_robot)
    T_weld, T_hold = layout.start_poses("i")
    q_hold = holder.model.ik(T_hold, homes[layout.holder_robot])
    straight = seamtrack.start_move_s(holder, homes[layout.holder_robot], q_hold)
    with pytest.raises(BadInput, match=r"^would collide: "):  # the straight move: through the welder
        guarded.refuse_colliding_move(cell, layout.holder_robot, homes[layout.holder_robot], q_hold, straight)
    route = seamtrack.start_route(cell, holder, homes[layout.holder_robot], q_hold, "holding pose of position (i)")
    assert len(route) == 2
    np.testing.assert_allclose(route[0], q_hold + seamtrack.DETOUR_DEG)
    np.testing.assert_allclose(route[1], q_hold)
    where[layout.holder_robot] = q_hold  # the holder at its holding pose: the welder goes straight
    q_weld = welder.model.ik(T_weld, homes[layout.tool_robot])
    route = seamtrack.start_route(cell, welder, homes[layout.tool_robot], q_weld, "start of position (i)")
    assert len(route) == 1
    np.testing.assert_allclose(route[0], q_weld)


def test_a_start_no_route_clears_is_refused_with_the_guards_line(monkeypatch):
    where: dict = {}
    cell, layout, homes = _setup("sim.toml", monkeypatch, where)
    holder = BrainArm(cell, layout.holder_robot)
    q_hold = holder.model.ik(layout.start_poses("i")[1], homes[layout.holder_robot])
    monkeypatch.setattr(seamtrack, "DETOUR_DEG", np.zeros(6))  # the detour is the straight move itself
    with pytest.raises(BadInput) as e:
        seamtrack.start_route(cell, holder, homes[layout.holder_robot], q_hold, "holding pose of position (i)")
    line = str(e.value)
    assert line.startswith(f"{layout.holder_robot} to the holding pose of position (i): would collide: ")
    assert line.endswith("(and no detour is clear)") and "\n" not in line


def test_a_cell_without_a_guard_table_keeps_the_cartesian_move(monkeypatch):
    cell, layout, homes = _setup("sim.toml", monkeypatch, {})
    del cell.raw["guard"]
    holder = BrainArm(cell, layout.holder_robot)
    assert seamtrack.start_route(cell, holder, homes[layout.holder_robot], homes[layout.holder_robot], "x") == []
