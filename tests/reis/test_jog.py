"""droid-jog: joint jogging before homing, from stdin lines (issue 4 §5)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from droid.brain.shmdb import cell_objects
from tests.brain.cellutil import ROOT, droid, make_cell_file, wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
def cell(tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name)
    out = droid("droid.brain.launcher", "up", "--cell", str(path), timeout=90)
    assert out.returncode == 0, out.stderr
    yield path
    out = droid("droid.brain.launcher", "down", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    assert cell_objects(cell_name) == []


def enc(path):
    out = droid("droid.tasks.snoop", "arm1", "--json", "--count", "1", "--rate", "50", "--cell", str(path))
    return np.asarray(json.loads(out.stdout)["encoder_pos"])


def jog(path, text):
    return subprocess.run([sys.executable, "-m", "droid.tasks.jog", "arm1", "--cell", str(path)], input=text,
                          capture_output=True, text=True, timeout=60, cwd=ROOT)


def test_joint_jog_before_homing_moves_by_the_deltas(cell):
    wait_for(lambda: not json.loads(droid("droid.tasks.snoop", "arm1", "--json", "--count", "1",
                                          "--cell", str(cell)).stdout)["stale"], what="arm1 fresh")
    start = enc(cell)
    out = jog(cell, "j6 +3000\nj1 -1500\n# a comment\nwait 0.2\nj6 +1000\n")
    assert out.returncode == 0, out.stderr
    want = start + np.array([-1500, 0, 0, 0, 0, 4000])

    def arrived():
        e = enc(cell)
        return bool(np.all(np.abs(e - want) <= 30)) and e.tolist()
    wait_for(arrived, timeout=20, what="jogged by the deltas")


def test_jog_bad_lines_and_cartesian_before_homing(cell):
    wait_for(lambda: not json.loads(droid("droid.tasks.snoop", "arm1", "--json", "--count", "1",
                                          "--cell", str(cell)).stdout)["stale"], what="arm1 fresh")
    start = enc(cell)
    out = jog(cell, "j9 +10\nj2 nan\nx +5\nj3 1.5\nspin 3\n")
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 5 and all(l.startswith("droid-jog: line ") for l in lines)
    assert "needs a homed arm" in lines[2]
    assert np.all(np.abs(enc(cell) - start) <= 30)  # nothing moved
