"""Speed and separation monitoring, the guard's core and the planner's protective stop (issue 41)."""
from __future__ import annotations

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.db.layouts import FAULT_COLLISION, FAULT_NAMES, fault_names
from droid.cli import BadInput
from droid.guard.ssm import CLEAR, SLOWING, STOPPED, SsmParams, ssm_params
from droid.guard.station import guard_core

from tests.guard.test_cell import SIM


def test_protective_separation_distance_is_the_sum_of_its_terms():
    p = SsmParams(reaction_s=0.1, stop_time_s=0.3, clearance_mm=25.0, uncertainty_mm=10.0, slow_mm=200.0)
    assert p.separation_mm(0.0) == pytest.approx(35.0)
    assert p.separation_mm(-500.0) == pytest.approx(35.0)  # separating: no speed term
    assert p.separation_mm(1000.0) == pytest.approx(1000.0 * (0.1 + 0.15) + 35.0)
    sp = p.separation_mm(1000.0)
    assert p.override(sp + 300.0, 1000.0) == 1.0 and p.state(sp + 300.0, 1000.0) == CLEAR
    assert p.override(sp + 100.0, 1000.0) == pytest.approx(0.5) and p.state(sp + 100.0, 1000.0) == SLOWING
    assert p.override(sp, 1000.0) == 0.0 and p.state(sp - 1.0, 1000.0) == STOPPED


@pytest.mark.parametrize("table,words", [
    ({"reaction": 1}, ["unknown key(s): reaction"]),
    ({"clearance_mm": -1}, ["clearance_mm", "[0, 1000]"]),
    ({"stop_time_s": float("nan")}, ["stop_time_s"]),
    ({"slow_mm": True}, ["slow_mm"]),
])
def test_bad_ssm_terms_are_one_line(table, words):
    with pytest.raises(BadInput) as e:
        ssm_params(table, "cell.toml")
    assert all(w in str(e.value) for w in words) and "\n" not in str(e.value)


def test_fault_collision_is_the_next_bit_and_named():
    assert FAULT_COLLISION == 256 and FAULT_NAMES[FAULT_COLLISION] == "collision"
    assert fault_names(128 | 256) == ["force", "collision"]
    from pathlib import Path

    header = (Path(__file__).resolve().parents[2] / "droid" / "include" / "droid_layouts.h").read_text()
    assert "#define DROID_FAULT_COLLISION 256" in header


def test_core_stops_arms_that_close_in_and_latches():
    core = guard_core(load_cell(SIM))
    far = {"arm1": np.zeros(6), "gmf1": np.zeros(6)}
    v = core.step(far)
    assert v.state == CLEAR and not v.stop and v.distance_mm > 300.0
    # the Reis swings its joint 1 toward the Fanuc's workpiece at full speed: the way-points ahead
    # come within the limit, or the distance falls inside S_p -- the stop trips before contact
    q = np.zeros(6)
    stopped_at = None
    for k in range(200):
        q = q + np.array([0.0, -100.0 / 60.0, 100.0 / 60.0, 0.0, 0.0, 0.0])
        v = core.step({"arm1": q, "gmf1": np.zeros(6)}, {"arm1": q + np.array([0, -100 / 60, 100 / 60, 0, 0, 0]),
                                                         "gmf1": np.zeros(6)})
        if v.stop:
            stopped_at = v.distance_mm
            break
    assert stopped_at is not None and stopped_at > core.params.clearance_mm
    assert v.state == STOPPED and v.override == {"arm1": 0.0, "gmf1": 0.0}
    assert core.step({"arm1": q, "gmf1": np.zeros(6)}).stop  # latched
    core.release()
    core.reset()
    assert not core.step(far).stop


def _planner_at_speed():
    from droid.kinematics import load_robot
    from droid.arm.planner import COLLISION_BRAKE_TICKS, PlannerCore

    core = PlannerCore(load_robot("reis_v15"))
    core.int_counts = np.zeros(6)
    core.ext_counts = np.full(6, 6000.0)
    core.time_count = 60  # 100 counts a tick
    return core, COLLISION_BRAKE_TICKS


def test_the_planner_ramps_a_protective_stop_down_along_the_path():
    core, n = _planner_at_speed()
    core._brake()
    steps = []
    from droid.arm.planner import PlanOutput

    prev = core.int_counts.copy()
    while core.time_count > 0:
        core._next_waypoint(PlanOutput())
        steps.append(float(core.int_counts[0] - prev[0]))
        prev = core.int_counts.copy()
    assert len(steps) == n
    assert all(a > b for a, b in zip(steps, steps[1:]))  # the speed ramps down
    assert steps[0] == pytest.approx(100.0 * n / (n + 1)) and steps[-1] == pytest.approx(100.0 / (n + 1))
    assert core.int_counts[0] == pytest.approx(100.0 * n / 2.0)  # the ramp's travel: n/2 steps
    assert core.brake_step is None
