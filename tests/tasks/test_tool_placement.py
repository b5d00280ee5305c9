"""The tool-tip sensor's readings carry capture stamps and are placed with the poses of that
instant (issue 12 item 2, "the same for the tool-tip sensor"): the world's stamped line, the
Brain's sensor Status (capture_age_us), droid-seamtrack's reading_of, TrackingCycle.place_tool."""
from __future__ import annotations

import math

import numpy as np
import pytest

from droid.brain.db.layouts import NO_CAPTURE_AGE, SENSOR_STATUS_LAYOUT
from droid.brain.plumbing.sensor_line import parse_line
from droid.brain.runtime.sensor_link import SensorStatusCore
from droid.brain.db.shmdb import MemoryDatabase
from droid.kinematics.transforms import trans
from droid.sim.mvs.devices import ToolSensorCore
from droid.sim.mvs.tool_sensor import pose_for_reading
from droid.sim.workpiece import load_workpiece
from droid.tasks.seam.params import SeamParams
from droid.tasks.seam.cycle import TrackingCycle
from droid.tasks.seam.delay import Reading
from droid.brain.cell.cell_layout import load_layout
from droid.tasks.seamtrack import reading_of

WRIST = load_layout().wrist("standard")
PERIOD_NS = int(1e9 / 60)


def test_a_stamping_tool_sensor_line_reaches_the_status_and_the_task_as_its_capture_tick():
    wp = load_workpiece("step_input")
    core = ToolSensorCore(wp, stamp=True)
    t_capture = 1_000_000_000_000 + 5 * PERIOD_NS  # the cell's CLOCK_MONOTONIC [ns]
    line = core.step(pose_for_reading(wp, 50.0, 0.4, -0.3, 0.0), t_capture)
    assert line.count(b",") == 3  # x,y,roll,ms
    r = parse_line(line.rstrip(b"\n"))
    assert r.valid and r.stamp_ms is not None and (r.x_mm, r.y_mm) == pytest.approx((0.4, -0.3), abs=1e-3)
    assert ToolSensorCore(wp).step(pose_for_reading(wp, 50.0)).count(b",") == 2  # plain unless asked
    link = SensorStatusCore()
    status = MemoryDatabase("tool", SENSOR_STATUS_LAYOUT)
    t_arrive = t_capture + 30_000_000  # 30 ms later, at heartbeat tick 7
    link.on_tick(6, b"invalid\n", t_capture)  # the port opened: the link syncs on a first line end
    status.update(**link.on_tick(7, line, t_arrive))
    rec = status.read()
    assert int(rec["capture_age_us"]) != NO_CAPTURE_AGE
    assert int(rec["capture_age_us"]) == pytest.approx(30_000, abs=1_000)  # ms resolution
    reading = reading_of(rec, PERIOD_NS)
    assert reading.stamp_tick == pytest.approx(7 - 30e6 / PERIOD_NS, abs=0.07)


def moving_cycle():
    """A tracking cycle whose Reis Status moves +1 mm in x per tick (holder fixed at identity)."""
    cyc = TrackingCycle(SeamParams(16.0), WRIST.T_wcp_tool, WRIST.T_wcp_sensor, heartbeat_hz=60.0)
    for tick in range(100, 140):
        cyc.remember(tick, trans(float(tick), 0.0, 0.0), tick, np.eye(4))
    return cyc


def test_a_tool_reading_is_placed_with_the_reis_pose_of_its_capture_instant():
    cyc = moving_cycle()
    r = Reading(0.0, 0.0, 0.0, True, stamp_tick=120.25)
    placed = cyc.place_tool(r, 122, WRIST.T_wcp_tool)
    # the Status of tick n shows the arm at n - STATUS_AGE_TICKS: x = t + status age
    assert placed.tick == 120.25
    assert placed.T_global_tool6[0, 3] == pytest.approx(120.25 + cyc.status_age_ticks)
    expected = trans(120.25 + cyc.status_age_ticks, 0, 0) @ WRIST.T_wcp_tool
    np.testing.assert_allclose(placed.seam_in_hold_mm, expected[:3, 3], atol=1e-9)
    # an unstamped reading: its Status tick minus the sensor lag
    un = cyc.place_tool(Reading(0.0, 0.0, 0.0, True), 122, WRIST.T_wcp_tool)
    assert un.tick == 122 - cyc.sensor_lag_ticks
    # a deviation shifts the measured seam point in the tool frame: x height, y lateral
    off = cyc.place_tool(Reading(1.0, 2.0, 0.0, True, stamp_tick=120.25), 122, WRIST.T_wcp_tool)
    d = np.linalg.inv(WRIST.T_wcp_tool[:3, :3]) @ (off.seam_in_hold_mm - placed.seam_in_hold_mm)
    np.testing.assert_allclose(d, [1.0, 2.0, 0.0], atol=1e-9)
    assert math.isnan(placed.travel_mm)  # no cycle has run yet: no travel known
    assert cyc.tool_dropped == 0 and cyc.dropped == 0


@pytest.mark.parametrize("stamp", [150.0, 20.0])
def test_a_tool_reading_from_the_future_or_older_than_the_history_is_dropped_and_counted(stamp):
    cyc = moving_cycle()
    assert cyc.place_tool(Reading(0.0, 0.0, 0.0, True, stamp_tick=stamp), 140, WRIST.T_wcp_tool) is None
    assert cyc.tool_dropped == 1 and cyc.dropped == 0  # the lead readings' count is not touched
    assert cyc.place_tool(Reading(valid=False), 140, WRIST.T_wcp_tool) is None
    assert cyc.tool_dropped == 1  # an invalid reading is not a dropped one


def test_in_a_lockstep_trial_the_placed_tool_readings_lie_on_the_seam():
    """With the exact holder and an exact tool-tip sensor, each tool reading placed with the Reis
    pose of its capture instant gives a point on the seam (the tool's error and the arm's Status
    sampling only), through the arc too.  On the ``fast`` arm, whose Status pose is its true
    pose: the full arm's encoders sit on the motor side of compliant drives, so its Status pose
    is off the true one by the drives' deflection (up to ~2 mm here), which is the point of it."""
    from droid.experiments.trial import TrialConfig, run_trial

    r = run_trial(TrialConfig("t", "vii", 32.0, workpiece="ramp_r200", sensor="ideal", holder="fixed",
                              tool_noise=False, arm="fast"))
    wp = load_workpiece("ramp_r200")
    pts = np.array(r.tool_seam_mm)
    assert len(pts) >= 0.9 * len(r.rows) and r.tool_dropped == 0
    near = np.array([wp.nearest(p) for p in pts])
    assert np.max(np.abs(near[:, 1])) <= 0.05 and np.max(np.abs(near[:, 2])) <= 0.05  # lateral, height
