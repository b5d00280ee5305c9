"""The joystick in a live cell: droid-snoop joy, droid-jog --joystick before and after homing (§3.4)."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from tests.brain.cellutil import cell_up, droid, make_cell_file, wait_for

pytestmark = pytest.mark.integration

DEFLECT = 0.6  # the twin's hand holds axis 0 here from power-on


@pytest.fixture
def cell(tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name)
    text = path.read_text()
    text = re.sub(r'(\[world\.devices\.joy_stick\][^\[]*?buttons = 8\n)',
                  lambda m: m.group(1) + f"script = [[0.0, [{DEFLECT}, 0.0], [0, 0, 0, 0, 0, 0, 0, 0]]]\n",
                  text, count=1)
    assert "script = " in text
    path.write_text(text)
    with cell_up(path, cell_name):
        yield path


def snoop(path, sub):
    out = droid("droid.tasks.snoop", sub, "--json", "--count", "1", "--rate", "50", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_joystick_drives_the_arm_before_and_after_homing(cell):
    joy = wait_for(lambda: (lambda d: not d["stale"] and d["valid"] and d)(snoop(cell, "joy")),
                   what="joy fresh and valid")
    assert joy["axes"][0] == pytest.approx(DEFLECT, abs=1e-3) and joy["axes"][1] == 0.0
    assert len(joy["buttons"]) == 16 and sum(joy["buttons"]) == 0 and joy["n_axes"] == 2
    wait_for(lambda: not snoop(cell, "arm1")["stale"], what="arm1 fresh")
    # joint mode, before homing: axis 0 drives joint 1 (JOG mode)
    start = np.asarray(snoop(cell, "arm1")["encoder_pos"])
    out = droid("droid.tasks.jog", "arm1", "--joystick", "joy", "--seconds", "2", "--cell", str(cell))
    assert out.returncode == 0, out.stderr
    moved = np.asarray(wait_for(lambda: (lambda e: e if abs(e[0] - start[0]) > 200 else None)(
        snoop(cell, "arm1")["encoder_pos"]), timeout=10, what="joint 1 jogged"))
    assert np.all(np.abs(moved[1:] - start[1:]) <= 30)  # only joint 1
    # home, then cartesian mode: axis 0 drives x
    out = droid("droid.tasks.home", "arm1", "--cell", str(cell), timeout=120)
    assert out.returncode == 0, out.stderr
    x0 = snoop(cell, "arm1")["x"]
    out = droid("droid.tasks.jog", "arm1", "--joystick", "joy", "--cart", "--seconds", "2", "--cell", str(cell))
    assert out.returncode == 0, out.stderr
    wait_for(lambda: snoop(cell, "arm1")["x"] > x0 + 10.0, timeout=10, what="wrist centre moved in +x")


def test_jog_refuses_a_subunit_that_is_not_a_joystick(cell):
    out = droid("droid.tasks.jog", "arm1", "--joystick", "mvs", "--seconds", "1", "--cell", str(cell))
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
