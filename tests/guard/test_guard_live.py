"""droid-guard run and droid-move's refusal on the live sim cell (issue 41; integration).

Written in the round that built the guard; run there once by mistake (a plain ``pytest
tests/guard``): the live guard's part passed, the target search (then joints 2 and 3 only)
found no colliding target and failed; the search is wider now and has not been run since.  On the session's shared homed cell: ``droid-guard run`` writes its
Status file (clear, a positive least distance, a pair), and a joint move of arm1 that the guard's
bodies say would collide with the Fanuc where it stands is refused by droid-move -- exit 2, one
line ``would collide: ...`` -- and arm1 does not move.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.brain.cellutil import ROOT, droid, wait_for
from tests.tasks.test_seamtrack_cell import snoop

pytestmark = pytest.mark.integration


def test_the_live_guard_reports_and_droid_move_refuses_a_colliding_move(homed_sim_cell):
    from droid.brain.cellfile import load_cell
    from droid.guard.cell import guard_scene
    from droid.guard.refuse import check_move
    from droid.kinematics import load_robot

    cell = load_cell(homed_sim_cell)
    status_file = cell.run_dir / "guard_status.json"
    status_file.unlink(missing_ok=True)
    p = subprocess.Popen([sys.executable, "-m", "droid.guard.cli", "run", "--cell", str(homed_sim_cell),
                          "--seconds", "20"], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(status_file.exists, timeout=10, what="the guard's Status file")
        st = json.loads(status_file.read_text())
        assert st["state"] == "clear" and st["distance_mm"] > 0 and all(st["pair"]), st
    finally:
        p.terminate()
        p.wait(timeout=10)

    scene = guard_scene(cell)
    reis, fanuc = load_robot("reis_v15"), load_robot("fanuc_s400")
    q1 = reis.gearing.counts_to_joints(np.asarray(snoop(homed_sim_cell, "arm1")["encoder_pos"], float))
    q2 = fanuc.gearing.counts_to_joints(np.asarray(snoop(homed_sim_cell, "gmf1")["encoder_pos"], float))
    goal = None
    # arm1 reaching forward toward the Fanuc and its workpiece: the first target within the joint
    # limits that the guard's bodies say would collide (a 1 deg grid over joints 1-3 and 5)
    grid = [(j1, j2, j3, j5) for j2 in range(-90, -29, 10) for j3 in range(0, 151, 15)
            for j1 in (0, -10, 10, -20, 20) for j5 in (0, 45, -45, 90, -90)]
    for j1, j2, j3, j5 in grid:
        g = q1.copy()
        g[0], g[1], g[2], g[4] = j1, j2, j3, j5
        if reis.limit_violation(g):
            continue
        if check_move(scene, "arm1", q1, g, 10.0, {"gmf1": q2}, limit_mm=35.0):
            goal = g
            break
    assert goal is not None, "no colliding target found from where the arms stand"
    counts = np.rint(reis.gearing.joints_to_counts(goal)).astype(int)
    before = snoop(homed_sim_cell, "arm1")["encoder_pos"]
    out = droid("droid.tasks.move", "arm1", "joint", *map(str, counts), "10", "--cell", str(homed_sim_cell))
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "would collide: arm1 " in lines[0], out.stderr
    time.sleep(0.5)
    after = snoop(homed_sim_cell, "arm1")["encoder_pos"]
    assert np.max(np.abs(np.subtract(after, before))) <= 2  # the arm never moved
