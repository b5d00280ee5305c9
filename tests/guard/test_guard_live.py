"""droid-guard on the live sim cell (issue 41; integration: they bring up nothing of their own but use
the session's shared homed cell, which declares [guard], so droid-cell up started droid-guard).

* the guard's Status database, through droid-snoop guard: fresh (its tick advancing), clear, a
  positive least distance and a pair;
* a joint move of arm1 into the Fanuc is refused by droid-move (exit 2, one ``would collide:`` line)
  and arm1 does not move;
* killing droid-guard stops every arm within the stale window: arm1 on a long move stands within
  ``stale_ticks`` + the protective stop's ramp (+ margin), FAULT_GUARD in both arms' Status, a NORMAL
  move refused meanwhile; ``droid-cell restart droid-guard`` clears it;
* a head-on course -- arm1 commanded straight at the Fanuc through the Brain's Command, bypassing
  droid-move's refusal -- gets a protective stop (FAULT_COLLISION) with the separation kept above
  the stated limit; the latch ends at rest and arm1 goes home again.

Written without a live run (the helper that wrote them was told not to start cells); the lead runs
``.venv/bin/python -m pytest -q -m integration tests/guard/test_guard_live.py``.
"""
from __future__ import annotations

import json
import os
import signal
import time

import numpy as np
import pytest

from tests.brain.cellutil import cell_status, droid, wait_for
from tests.tasks.test_seamtrack_cell import snoop

pytestmark = pytest.mark.integration

SNOOP, MOVE, CELL = "droid.tasks.snoop", "droid.tasks.move", "droid.brain.launcher"


def guard_status(cell_file) -> dict:
    out = droid(SNOOP, "guard", "--json", "--count", "1", "--rate", "50", "--cell", str(cell_file))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def _scene_and_models(cell_file):
    from droid.brain.cellfile import load_cell
    from droid.guard.cell import guard_scene
    from droid.kinematics import load_robot

    cell = load_cell(cell_file)
    return cell, guard_scene(cell), {n: load_robot(cell.subunits[n].robot) for n in ("arm1", "gmf1")}


def _joints(cell_file, models) -> dict:
    return {n: m.gearing.counts_to_joints(np.asarray(snoop(cell_file, n)["encoder_pos"], float)) for n, m in models.items()}


def _guard_pid(cell_file) -> int:
    (row,) = [p for p in cell_status(cell_file) if p.get("name", p.get("prog", "")).startswith("droid-guard")]
    return int(row["pid"])


def test_the_live_guard_keeps_its_status_database(homed_sim_cell):
    a = guard_status(homed_sim_cell)
    time.sleep(0.5)
    b = guard_status(homed_sim_cell)
    assert b["tick"] > a["tick"] >= 1  # fresh: a pass every heartbeat tick
    assert b["state"] == "clear" and b["distance_mm"] > 0 and all(b["pair"]), b
    assert set(b["override"]) == {"arm1", "gmf1"} and b["stale_ticks"] >= 2 and b["cycle_us"] > 0


def test_droid_move_refuses_a_colliding_move(homed_sim_cell):
    from droid.guard.refuse import check_move

    _, scene, models = _scene_and_models(homed_sim_cell)
    reis = models["arm1"]
    q = _joints(homed_sim_cell, models)
    goal = None
    # arm1 reaching forward toward the Fanuc and its workpiece: the first target within the joint
    # limits that the guard's bodies say would collide (a grid over joints 1-3 and 5)
    grid = [(j1, j2, j3, j5) for j2 in range(-90, -29, 10) for j3 in range(0, 151, 15)
            for j1 in (0, -10, 10, -20, 20) for j5 in (0, 45, -45, 90, -90)]
    for j1, j2, j3, j5 in grid:
        g = q["arm1"].copy()
        g[0], g[1], g[2], g[4] = j1, j2, j3, j5
        if not reis.limit_violation(g) and check_move(scene, "arm1", q["arm1"], g, 10.0, {"gmf1": q["gmf1"]}):
            goal = g
            break
    assert goal is not None, "no colliding target found from where the arms stand"
    counts = np.rint(reis.gearing.joints_to_counts(goal)).astype(int)
    before = snoop(homed_sim_cell, "arm1")["encoder_pos"]
    out = droid(MOVE, "arm1", "joint", *map(str, counts), "10", "--cell", str(homed_sim_cell))
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "would collide: arm1 " in lines[0], out.stderr
    time.sleep(0.5)
    after = snoop(homed_sim_cell, "arm1")["encoder_pos"]
    assert np.max(np.abs(np.subtract(after, before))) <= 2  # the arm never moved


def test_killing_droid_guard_stops_every_arm_within_the_stale_window(homed_sim_cell):
    from droid.brain import arm_command
    from droid.brain.cellfile import load_cell
    from droid.brain.databases import open_brain
    from droid.guard.gate import guard_stale_ticks
    from droid.subunits.reis.planner import COLLISION_BRAKE_TICKS

    cell = load_cell(homed_sim_cell)
    window_s = (guard_stale_ticks(cell) + COLLISION_BRAKE_TICKS) / cell.heartbeat_hz + 0.25  # + the servo's lag
    models = _scene_and_models(homed_sim_cell)[2]
    home = np.asarray(snoop(homed_sim_cell, "arm1")["encoder_pos"], int)
    away = home + np.rint(models["arm1"].gearing.joints_to_counts(np.array([-30.0, 0, 0, 0, 0, 0]))
                          - models["arm1"].gearing.joints_to_counts(np.zeros(6))).astype(int)
    command = open_brain(cell, cell.subunit("arm1"), "command")
    try:
        arm_command.joint(command, away, int(8.0 * cell.heartbeat_hz))  # a slow 8 s move: still on it when killed
        time.sleep(1.5)
        os.kill(_guard_pid(homed_sim_cell), signal.SIGKILL)
        t_kill = time.monotonic()
        time.sleep(window_s)
        a = snoop(homed_sim_cell, "arm1")
        time.sleep(0.3)
        b = snoop(homed_sim_cell, "arm1")
        assert time.monotonic() - t_kill < window_s + 2.0
        assert np.max(np.abs(np.subtract(a["encoder_pos"], b["encoder_pos"]))) <= 2, "arm1 still moving"
        assert np.max(np.abs(np.subtract(b["encoder_pos"], away))) > 1000  # stopped short of the target
        for arm in ("arm1", "gmf1"):
            assert "guard" in snoop(homed_sim_cell, arm)["fault"]
        out = droid(MOVE, "arm1", "joint", *map(str, home), "3", "--cell", str(homed_sim_cell))
        assert out.returncode != 0  # refused while the guard is gone
    finally:
        out = droid(CELL, "restart", "droid-guard", "--cell", str(homed_sim_cell))
        command.close()
    assert out.returncode == 0, out.stderr
    wait_for(lambda: "guard" not in snoop(homed_sim_cell, "arm1")["fault"], timeout=10, what="FAULT_GUARD to clear")
    out = droid(MOVE, "arm1", "joint", *map(str, home), "4", "--cell", str(homed_sim_cell))
    assert out.returncode == 0, out.stderr


def test_a_head_on_course_gets_a_protective_stop(homed_sim_cell):
    from droid.brain import arm_command
    from droid.brain.databases import open_brain
    from droid.guard.refuse import check_move

    cell, scene, models = _scene_and_models(homed_sim_cell)
    q = _joints(homed_sim_cell, models)
    start = np.asarray(snoop(homed_sim_cell, "arm1")["encoder_pos"], int)
    goal = None
    for j2 in range(-20, -91, -10):  # arm1 stretching forward at the Fanuc: the first path that would meet it
        for j3 in range(0, 121, 20):
            g = q["arm1"].copy()
            g[1], g[2] = j2, j3
            if not models["arm1"].limit_violation(g) and check_move(scene, "arm1", q["arm1"], g, 3.0,
                                                                   {"gmf1": q["gmf1"]}, limit_mm=0.0):
                goal = g  # the unguarded path goes into the Fanuc's bodies
                break
        if goal is not None:
            break
    assert goal is not None, "no head-on course found from where the arms stand"
    command = open_brain(cell, cell.subunit("arm1"), "command")
    least = np.inf
    try:
        # through the Brain's Command (BrainArm's way), not droid-move: nothing refuses it before it moves
        arm_command.joint(command, np.rint(models["arm1"].gearing.joints_to_counts(goal)).astype(int),
                          int(3.0 * cell.heartbeat_hz))
        t0 = time.monotonic()
        while time.monotonic() - t0 < 5.0:
            least = min(least, scene.closest(_joints(homed_sim_cell, models)).distance_mm)
            st = guard_status(homed_sim_cell)
            if st["state"] == "stopped":
                break
        assert st["state"] == "stopped" and st["trips"] >= 1, st
        assert "collision" in snoop(homed_sim_cell, "arm1")["fault"]
        time.sleep(1.0)  # at rest
        least = min(least, scene.closest(_joints(homed_sim_cell, models)).distance_mm)
        assert least > 25.0  # the stated limit C
    finally:
        wait_for(lambda: "collision" not in snoop(homed_sim_cell, "arm1")["fault"], timeout=10,
                 what="the latch to end at rest")
        out = droid(MOVE, "arm1", "joint", *map(str, start), "4", "--cell", str(homed_sim_cell))
        command.close()
    assert out.returncode == 0, out.stderr
