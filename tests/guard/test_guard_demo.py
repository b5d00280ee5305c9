"""The README demo's motions with the live guard on, in lockstep, on each shipped cell (issue 41;
docs/guard.md §9).

The whole cell in lockstep with droid-guard's station and the planners' gates from the first tick
(tests/guard/demo.py), the motions of ``scripts/demo.sh`` through the arms' Brain Commands:

* homing both arms (the welder, then the holder): no stop -- an arm not homed is not judged, the
  GMF1's counts zeroed at homing are a new course, not a speed;
* the holder to the holding pose of position (i), the welder to the start, tracking 400 mm of the
  seam at 16 mm/s in plus mode: no stop and no override below 1 -- with the holder brought to its
  holding pose by a joint move through a pose clear of the welder;
* the holder's straight move (droid-seamtrack's 3 s cartesian move before its start moves were
  routed, droid.tasks.seamtrack.start_route; the welder at its home pose) sweeps the held workpiece through the welder's upper arm -- the bodies overlap by 46 mm (the
  Reis) and 88 mm (the ABB) unguarded, measured with the guard watching: a collision, not a
  conservative speed -- and the guard stops it above the stated limit C.

reis_pair.toml (two Reis-class arms, no holder): homing both and the welder's move to the start of
position (i).  The head-on and crossing courses that must still stop: tests/guard/test_guard_trials.py.
"""
from __future__ import annotations

import pytest

from droid.tasks.seamtrack import DETOUR_DEG
from tests.guard.demo import DemoRun

#: the holder's route to its holding pose: first to the holding pose's joints turned by these [deg]
#: (joint 1 away from the welder, the upper arm and forearm back), clear of the welder at home --
#: droid-seamtrack's own detour (start_route)
VIA_DEG = DETOUR_DEG
C_MM = 25.0  # the shipped cells' [guard] ssm: the stated limit ...
CZ_MM = 35.0  # ... and C + Z


@pytest.mark.parametrize("cell", ["sim.toml", "abb_weld.toml"])
def test_the_demo_motions_pass_with_the_guard_on(cell):
    r = DemoRun(cell)
    try:
        welder, holder = r.layout.tool_robot, r.layout.holder_robot
        phases = [r.home(welder), r.home(holder)]
        T_welder, T_holder = r.start_poses()
        q_hold = r.model(holder).ik(T_holder, r.joints(holder))
        phases.append(r.move_joint(holder, q_hold + VIA_DEG, 3.0, "holder clear of the welder"))
        phases.append(r.move_joint(holder, q_hold, 3.0, "holder to the holding pose of (i)"))
        phases.append(r.move_to_start(welder, T_welder, "welder to the start of (i)"))
        phases.append(r.track(16.0, 400.0, "plus"))
        for ph in phases:
            print(ph.line())
        for ph in phases:
            assert ph.ok, ph.line()
            assert ph.trips == 0 and ph.min_override == 1.0 and set(ph.states) == {"clear"}, ph.line()
            assert ph.least_mm > CZ_MM and ph.max_sp_mm < ph.least_mm, ph.line()
        notes = r.guard.notes
        assert any(n.startswith(f"{holder} not homed: ") for n in notes)
        assert f"{holder} homed: its pairs are judged again (a new course)" in notes
        assert r.guard.core.trips == 0
    finally:
        r.close()


@pytest.mark.parametrize("cell,pair", [("sim.toml", ("arm1.link_3", "gmf1.workpiece")),
                                       ("abb_weld.toml", ("abb.link_3", "gmf1.workpiece"))])
def test_the_demos_own_holder_move_is_a_collision_and_stopped_above_the_limit(cell, pair):
    r = DemoRun(cell)
    try:
        welder, holder = r.layout.tool_robot, r.layout.holder_robot
        assert r.home(welder).trips == 0 and r.home(holder).trips == 0
        _, T_holder = r.start_poses()
        ph = r.move_to_start(holder, T_holder, "holder to the holding pose (the straight cartesian move)")
        r.sched.run_for(1.0)  # at rest
        print(ph.line())
        assert not ph.ok and ph.trips == 1, ph.line()  # FAULT_COLLISION: the KAREL move halted
        d, trip_pair, closing, sp = ph.trip
        assert trip_pair == pair and d <= sp and d > CZ_MM  # the welder's upper arm and the workpiece
        assert closing < 400.0  # the pair's own approach (the old rule's sum was about 300 at rest-to-rest)
        assert ph.least_mm > C_MM, ph.line()  # the stated limit kept
    finally:
        r.close()


def test_the_reis_pair_homes_and_moves_with_the_guard_on():
    r = DemoRun("reis_pair.toml")
    try:
        phases = [r.home("arm1"), r.home("arm2")]
        T_welder, _ = r.start_poses()
        phases.append(r.move_to_start("arm1", T_welder, "arm1 to the start of (i)"))
        for ph in phases:
            print(ph.line())
            assert ph.ok and ph.trips == 0 and ph.min_override == 1.0 and set(ph.states) == {"clear"}, ph.line()
        assert r.guard.core.trips == 0
    finally:
        r.close()
