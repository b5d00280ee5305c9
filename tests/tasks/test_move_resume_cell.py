"""droid-move rides through a protective stop on the live cell (issue 40 item 4).

On the session's shared homed cell (tests/conftest.py ``homed_sim_cell``): a slow joint move of
arm1, and in its middle droid-servo-agent of arm1 paused (SIGSTOP) for 150 ms -- a host stall
of the kind docs/safety.md lists: the servo's queue runs dry and it brakes; the agent wakes to a
queue of old reports and sets FAULT_BRAKING; the planner cancels the move ("cancelled command N:
faults: braking").  (droid-servo itself is not the one paused: silent for more than 100 ms its
watchdog latches the amplifiers off, a hard fault that needs a power cycle.)  The move resumes
from where the arm stopped and ends at its target (exit 0); with ``--no-resume`` it fails as
before (exit 1).  The decisions themselves: tests/tasks/test_move_resume.py.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.brain.cellutil import ROOT, wait_for
from tests.reis.test_reis_cell import _local_pos, pid_of, snoop

pytestmark = pytest.mark.integration
PAUSE_S = 0.15
MOVE_S = 8.0
#: 27 deg on joint 1 and 54 deg on joint 6 in 8 s: slow enough that the pause lands mid-move
OFFSETS = np.array([30000, 0, 0, 0, 0, 60000])


def _move_paused_midway(cell, *extra: str):
    """droid-move arm1 joint to a target OFFSETS away, droid-servo-agent arm1 paused for PAUSE_S
    once the arm covered a fifth of the way; (exit code, stderr, target [counts])."""
    start = np.asarray(snoop(cell)["encoder_pos"])
    target = start + (-1 if start[0] > OFFSETS[0] // 2 else 1) * OFFSETS  # away from where it stands
    agent = pid_of(cell, "droid-servo-agent arm1")
    mv = subprocess.Popen([sys.executable, "-m", "droid.tasks.move", "arm1", "joint", *map(str, target.tolist()),
                           str(MOVE_S), *extra, "--cell", str(cell)], cwd=ROOT, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: abs(_local_pos(cell)[0] - start[0]) > OFFSETS[0] // 5, timeout=30,
                 interval=0.02, what="arm1 a fifth of the way")
        os.kill(agent, signal.SIGSTOP)
        try:
            at = _local_pos(cell)
            time.sleep(PAUSE_S)
        finally:
            os.kill(agent, signal.SIGCONT)
        assert abs(int(at[0]) - int(target[0])) > 5000, f"the move was nearly done ({at.tolist()}) at the pause"
        _, err = mv.communicate(timeout=120)
    finally:
        if mv.poll() is None:
            mv.kill()
            mv.communicate()
    return mv.returncode, err, target


def test_a_move_stopped_by_braking_resumes_and_arrives(homed_sim_cell):
    code, err, target = _move_paused_midway(homed_sim_cell)
    assert code == 0, err
    assert "resuming from the arm's position (1 of 3)" in err, err
    assert re.search(r"^arm1: protective stop at \d+ % of the move \(braking\); resuming from the arm's "
                     r"position \(1 of 3\)$", err, re.M), err
    assert re.search(r"^arm1: arrived after [1-3] resumes?$", err, re.M), err
    assert "Traceback" not in err
    wait_for(lambda: np.all(np.abs(np.asarray(snoop(homed_sim_cell)["encoder_pos"]) - target) <= 20),
             timeout=10, what="arm1 at the target")


def test_a_move_stopped_by_braking_with_no_resume_fails(homed_sim_cell):
    code, err, target = _move_paused_midway(homed_sim_cell, "--no-resume")
    assert code == 1, err
    assert "resuming" not in err and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and re.match(r"^droid-move: arm1 failed command \d+ \(faults.*braking.*\)$", lines[0]), err
    assert np.any(np.abs(np.asarray(snoop(homed_sim_cell)["encoder_pos"]) - target) > 1000)  # not carried on
