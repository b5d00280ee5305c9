"""The planners' side of the guard (issue 41 items 2-3): the stale rule and the speed override.

A PlannerStation with a GuardGate over in-memory controller records: a NORMAL move is refused
until the guard's record is fresh, runs as without a gate at override 1, takes twice the ticks
at 0.5, ends along its path (and FAULT_GUARD is set) when the record goes stale; and the
guard's station writes its tick and overrides into the arms' Commands and its own Status.
"""
from __future__ import annotations

import numpy as np
import pytest

from droid.brain.db import layouts as L
from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.brain.db.shmdb import MemoryDatabase
from droid.cli import BadInput
from droid.guard.gate import DEFAULT_STALE_TICKS, GuardGate, guard_stale_ticks
from droid.kinematics import load_robot
from droid.arm.planner import COLLISION_BRAKE_TICKS, PlannerCore, PlannerStation

MODEL = load_robot("reis_v15")
TARGET = np.array([4000, -3000, 2000, 1000, -500, 800])


def station(gate: bool = True):
    cmd = MemoryDatabase("c", L.CTRL_COMMAND_LAYOUT)
    st = MemoryDatabase("s", L.CTRL_STATUS_LAYOUT)
    cmd.update(link_alive=1, cmd_mode=L.NORMAL_MODE, coord=L.JSPACE)
    st.update(homed=1, encoder_pos=[0] * 6)
    return PlannerStation(PlannerCore(MODEL), cmd, st, GuardGate(DEFAULT_STALE_TICKS) if gate else None)


def command(s, ticks=30, cmd_id=1):
    s.ctrl_command.update(encoder_cmd_ext=TARGET, joint_time_count=ticks, cmd_id=cmd_id)


def run(s, ticks, first=1, guard=True, override=1.0):
    outs = []
    for t in range(first, first + ticks):
        if guard:
            s.ctrl_command.update(guard_tick=t - 1 if t > 1 else t, guard_override=override)
        outs.append(s.cycle(t))
    return outs


def test_no_normal_move_before_the_guard_has_run():
    s = station()
    run(s, 2, guard=False)
    assert int(s.ctrl_status.read()["fault"]) & L.FAULT_GUARD
    command(s)
    (out,) = run(s, 1, first=3, guard=False)
    assert out.cmd_result == L.CMD_REFUSED and "guard" in out.note
    assert out.encoder_cmd_int.tolist() == [0] * 6


def test_at_override_1_a_move_is_the_same_as_without_a_gate():
    ways = []
    for gate in (False, True):
        s = station(gate)
        run(s, 2, guard=gate)
        command(s)
        ways.append([o.encoder_cmd_int.tolist() for o in run(s, 35, first=3, guard=gate)])
        assert not int(s.ctrl_status.read()["fault"]) & L.FAULT_GUARD
    assert ways[0] == ways[1] and ways[0][29] == TARGET.tolist()


def test_at_override_half_a_move_takes_twice_the_ticks():
    s = station()
    run(s, 2)
    command(s, ticks=30)
    outs = run(s, 80, first=3, override=0.5)
    done = next(i for i, o in enumerate(outs) if o.encoder_cmd_int.tolist() == TARGET.tolist())
    # the applied speed falls from 1 to 0.5 over 8 ticks (RAMP 1/15 a tick), then 0.5 a tick
    assert 55 <= done <= 60, done
    steps = np.diff([o.encoder_cmd_int[0] for o in outs[:done]])
    assert abs(steps[20] - TARGET[0] / 30 * 0.5) <= 1  # half the nominal step
    assert outs[done].busy == 0


def test_a_guard_gone_stale_ends_the_move_along_its_path():
    s = station()
    run(s, 2)
    command(s, ticks=120)
    run(s, 30, first=3)
    mid = s.ctrl_command.read()["encoder_cmd_int"].copy()
    outs = [s.cycle(t) for t in range(33, 33 + DEFAULT_STALE_TICKS + COLLISION_BRAKE_TICKS + 5)]  # no guard ticks
    assert int(s.ctrl_status.read()["fault"]) & L.FAULT_GUARD
    failed = [o for o in outs if o.cmd_result == L.CMD_FAILED]
    assert failed and "faults: guard" in failed[0].note
    end = outs[-1].encoder_cmd_int
    assert outs[-2].encoder_cmd_int.tolist() == end.tolist()  # standing
    assert np.all(np.abs(end - mid) < np.abs(TARGET - mid))  # short of the target, on the way to it
    assert outs[-1].busy == 0
    command(s, cmd_id=2)  # while stale a new move is refused
    assert s.cycle(60).cmd_result == L.CMD_REFUSED
    run(s, 1, first=61)  # the guard back: the bit clears
    assert not int(s.ctrl_status.read()["fault"]) & L.FAULT_GUARD


def test_stale_ticks_from_the_cell_file(tmp_path):
    sim = load_cell(BUNDLED_CELLS / "sim.toml")
    assert guard_stale_ticks(sim) == DEFAULT_STALE_TICKS  # the shipped cell runs the live guard
    on = (BUNDLED_CELLS / "sim.toml").read_text()
    assert "\nrun = true\n" in on
    (tmp_path / "off.toml").write_text(on.replace("\nrun = true\n", "\nrun = false\n", 1))
    assert guard_stale_ticks(load_cell(tmp_path / "off.toml")) is None  # run = false: no live guard
    (tmp_path / "odd.toml").write_text(on.replace("\nrun = true\n", "\nrun = 1\n", 1))
    with pytest.raises(BadInput, match=r"\[guard\] run: must be true or false, got 1"):
        guard_stale_ticks(load_cell(tmp_path / "odd.toml"))
    text = on.replace("[guard]\n", "[guard]\nstale_ticks = 1\n", 1)
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(BadInput, match=r"\[guard\] stale_ticks: must be an integer in \[2, 600\]"):
        guard_stale_ticks(load_cell(bad))


def test_the_station_writes_its_tick_and_overrides_into_the_commands_and_its_status():
    from droid.guard.station import GuardStation, guard_core, guard_status_dict

    cell = load_cell(BUNDLED_CELLS / "sim.toml")
    core = guard_core(cell)
    arms, homes = {}, {}
    for name in core.scene.arms:
        model = load_robot(cell.subunits[name].robot)
        brain = MemoryDatabase(f"{name}.status", L.ARM_STATUS_LAYOUT)
        counts = np.rint(model.gearing.joints_to_counts(np.asarray(model.home_switch_deg, float)))
        brain.update(encoder_pos=counts, encoder_cmd=counts, homed=1)  # homed: judged (docs/guard.md §5)
        homes[name] = model.gearing.counts_to_joints(counts)
        arms[name] = (model.gearing, brain, MemoryDatabase(f"{name}.ctrl_status", L.CTRL_STATUS_LAYOUT),
                      MemoryDatabase(f"{name}.command", L.ARM_COMMAND_LAYOUT))
    db = MemoryDatabase("guard.status", L.GUARD_STATUS_LAYOUT)
    s = GuardStation(core, arms, db, stale_ticks=7)
    s.on_tick(41)
    for name, (*_, command) in arms.items():
        c = command.read()
        assert int(c["guard_tick"]) == 41 and float(c["guard_override"]) == 1.0
    d = guard_status_dict(db.read())
    want = core.scene.closest(homes)
    assert d["tick"] == 41 and d["state"] == "clear" and d["stale_ticks"] == 7 and d["cycles"] == 1
    assert d["distance_mm"] == pytest.approx(want.distance_mm, abs=1e-9)
    assert set(d["pair"]) == {want.a.key, want.b.key}
    assert d["override"] == {"arm1": 1.0, "gmf1": 1.0} and d["pairs"] == core.scene.n_pairs and d["cycle_us"] > 0
    s.enabled = False  # "guard off" (a trial's reposition): the tick still stamped, override 1
    s.on_tick(42)
    assert all(int(cmd.read()["guard_tick"]) == 42 for *_, cmd in arms.values())


def test_a_move_target_in_encoder_cmd_is_not_taken_for_a_way_point():
    """The GMF1 reports its KAREL move's target in ``encoder_cmd`` (zeros when idle), not a next
    way-point: only the arms in ``waypoints`` have it read as one.  Both arms stand still; the
    Fanuc's encoder_cmd lies 9 deg away on joints 1 and 2 (a move's end, as live): taken as a
    way-point it reads as a closing speed of metres a second and stops the cell, as it did live."""
    from droid.guard.station import GuardStation, guard_core

    cell = load_cell(BUNDLED_CELLS / "sim.toml")

    def station(waypoints):
        core = guard_core(cell)
        arms = {}
        for name in core.scene.arms:
            model = load_robot(cell.subunits[name].robot)
            q = np.asarray(model.home_switch_deg, float)
            brain = MemoryDatabase(f"{name}.status", L.ARM_STATUS_LAYOUT)
            target = q + (np.array([9.0, -9.0, 0, 0, 0, 0]) if name == "gmf1" else 0.0)
            brain.update(encoder_pos=np.rint(model.gearing.joints_to_counts(q)),
                         encoder_cmd=np.rint(model.gearing.joints_to_counts(target)), homed=1)
            arms[name] = (model.gearing, brain, MemoryDatabase(f"{name}.ctrl_status", L.CTRL_STATUS_LAYOUT),
                          MemoryDatabase(f"{name}.command", L.ARM_COMMAND_LAYOUT))
        return GuardStation(core, arms, None, stale_ticks=7, waypoints=waypoints)

    wrong, right = station(None), station({"arm1"})
    for tick in (1, 2, 3):
        wrong.on_tick(tick)
        right.on_tick(tick)
    assert wrong.last.closing_mm_s > 1000.0 and wrong.last.state == "stopped"
    assert right.last.closing_mm_s == 0.0 and right.last.state == "clear" and right.core.trips == 0


def test_the_fault_campaign_pauses_and_kills_droid_guard_in_a_cell_with_a_guard():
    from droid.faults.campaign import GUARD_TARGETS, plan

    assert plan(200, 1, guard=False) == plan(200, 1)  # the draws of a cell without a guard are as they were
    targets = {(f.kind, f.target) for f in plan(400, 3, guard=True)}
    assert ("pause", GUARD_TARGETS[0]) in targets and ("kill", GUARD_TARGETS[0]) in targets
