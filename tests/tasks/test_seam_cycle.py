"""The tracking cycle shared by droid-seamtrack and the lockstep trial (issue 12 item 1):
cycle counting from the heartbeat, the stamped pose histories, a reading placed with the
pose of its own instant."""
from __future__ import annotations

import numpy as np
import pytest

from droid.kinematics.transforms import trans
from droid.tasks.seam.params import SeamParams
from droid.tasks.seam.cycle import PoseHistory, TrackingCycle, cycle_ticks_for, interpolate_pose
from droid.tasks.seam.delay import Reading
from droid.brain.cell.cell_layout import load_layout

WRIST = load_layout().wrist("standard")


@pytest.mark.parametrize("hz, ticks", [(60.0, 2), (30.0, 1), (120.0, 4), (90.0, 3)])
def test_cycle_ticks_follow_the_heartbeat(hz, ticks):
    assert cycle_ticks_for(hz, 30.0) == ticks


@pytest.mark.parametrize("hz", [50.0, 20.0, 45.0, 0.0, -60.0, float("nan")])
def test_a_heartbeat_that_cannot_serve_30_hz_is_refused(hz):
    with pytest.raises(ValueError):
        cycle_ticks_for(hz, 30.0)
    with pytest.raises(ValueError):
        TrackingCycle(SeamParams(16.0), WRIST.T_wcp_tool, WRIST.T_wcp_sensor, heartbeat_hz=hz)


def test_due_counts_cycles_and_log_rows_and_steps_once_after_a_late_wake_up():
    cyc = TrackingCycle(SeamParams(16.0), WRIST.T_wcp_tool, WRIST.T_wcp_sensor, heartbeat_hz=120.0)
    assert (cyc.cycle_ticks, cyc.log_ticks) == (4, 12)
    due = [t for t in range(100, 120) if cyc.due(t)]
    assert due == [100, 104, 108, 112, 116]
    assert cyc.due(131) and not cyc.due(132) and cyc.due(135)  # late: one step, then on again
    logs = [t for t in range(0, 40) if cyc.log_due(t)]
    assert logs == [11, 23, 35]


def test_pose_history_interpolates_and_refuses_outside_its_span():
    h = PoseHistory(span_ticks=10)
    for t in range(20):
        h.add(t, trans(2.0 * t, 0.0, 0.0))
    assert h.at(15.25)[0, 3] == pytest.approx(30.5)
    assert h.at(20.5) is None  # the future
    assert h.at(5.0) is None  # older than the span
    Rz = np.eye(4)
    Rz[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
    half = interpolate_pose(np.eye(4), Rz, 0.5)
    assert np.degrees(np.arctan2(half[1, 0], half[0, 0])) == pytest.approx(45.0)


def test_a_reading_is_placed_with_the_pose_of_its_capture_and_a_future_one_is_dropped():
    cyc = TrackingCycle(SeamParams(16.0, dead_zone_cycles=0), WRIST.T_wcp_tool, WRIST.T_wcp_sensor,
                        heartbeat_hz=60.0)
    T_hold = np.eye(4)
    for t in range(10):
        cyc.remember(t, trans(10.0 * t, 0.0, 0.0), t, T_hold)
    r = Reading(0.0, 0.0, 0.0, True)
    # Status tick 9, lag 1 tick: captured at 8, shown by the Status of 8.75 (STATUS_AGE_TICKS)
    sensed = cyc.locate(Reading(0.0, 0.0, 0.0, True, stamp_tick=cyc.capture_tick(9)))
    assert sensed[0][0, 3] == pytest.approx(10.0 * (8 + 0.75))
    assert cyc.locate(Reading(stamp_tick=50.0)) is None and cyc.dropped == 1
    out = cyc.step(T_hold, trans(90.0, 0, 0), 9, r, 9)
    assert out.stop is None and cyc.dropped == 1


def test_the_real_time_shell_reads_the_capture_instant_from_the_sensor_status():
    from droid.brain.db.layouts import NO_CAPTURE_AGE, SENSOR_STATUS
    from droid.tasks.seamtrack import reading_of

    rec = np.zeros((), SENSOR_STATUS)
    rec["R"] = np.eye(3)
    rec["tick"], rec["x"], rec["y"] = 600, 0.5, -1.0
    rec["capture_age_us"] = 25_000  # 1.5 ticks of 60 Hz
    r = reading_of(rec, int(round(1e9 / 60)))
    assert r.valid and r.stamp_tick == pytest.approx(598.5, abs=1e-3)
    rec["capture_age_us"] = NO_CAPTURE_AGE
    assert reading_of(rec, int(round(1e9 / 60))).stamp_tick is None  # the cycle assumes the lag
    rec["homed"] = 1
    assert not reading_of(rec).valid


def test_stamped_is_replace_with_the_capture_instant():
    """The cycle's stamping (droid.tasks.seam.cycle.stamped) gives what dataclasses.replace gives,
    for a plain Reading and for a subclass of it."""
    from dataclasses import dataclass, replace

    from droid.tasks.seam.cycle import stamped
    from droid.tasks.seam.delay import Reading

    @dataclass(frozen=True)
    class Tagged(Reading):
        tag: str = "t"

    for r in (Reading(1.5, -0.25, 0.01, True), Reading(0.0, 0.0, 0.0, False), Reading(2.0, 1.0, -0.5, True, True, 3.0),
              Tagged(1.0, 2.0, 3.0, True, tag="x")):
        got, want = stamped(r, 41.25), replace(r, stamp_tick=41.25)
        assert got == want and type(got) is type(want), (got, want)
