"""The seam tracker's station (droid.tasks.seam.station; issue 25 item 3): the one cycle both
droid-seamtrack and the lockstep trial call, with its stale rule counted in heartbeat ticks.

No cell: the station is fed ArmStatus values as a shell would read them."""
from __future__ import annotations

import numpy as np
import pytest

from droid.tasks.seam.params import SeamParams
from droid.tasks.seam.stops import STOP_FAULT, STOP_STALE
from droid.tasks.seam.cycle import TrackingCycle
from droid.tasks.seam.delay import INVALID_READING
from droid.brain.cell.cell_layout import load_layout
from droid.tasks.seam.station import STALE_GRACE_S, ArmStatus, SeamtrackStation, stale_grace_ticks
from droid.brain.db.layouts import FAULT_SERVO

LAYOUT = load_layout()
WRIST = LAYOUT.wrist("standard")
T_REIS, T_HOLD = LAYOUT.start_poses("i", "standard")
NEVER_LOST = 10_000


def station(hz: float = 60.0, **kw) -> SeamtrackStation:
    cyc = TrackingCycle(SeamParams(16.0, lost_cycles=NEVER_LOST), WRIST.T_wcp_tool, WRIST.T_wcp_sensor,
                        heartbeat_hz=hz)
    return SeamtrackStation(cyc, hz, **kw)


def arms(tick: int, stale_from: int | None = None, fault: int = 0, status_tick: int | None = None):
    stale = stale_from is not None and tick >= stale_from
    st = status_tick if status_tick is not None else (stale_from if stale else tick)  # a stale record stops
    return (ArmStatus("arm1", st, T_REIS, fault, stale), ArmStatus("gmf1", st, T_HOLD, 0, False))


def lead():
    return INVALID_READING, 0


@pytest.mark.parametrize("hz", [60.0, 120.0, 30.0])
def test_the_stale_grace_is_counted_in_heartbeat_ticks(hz):
    assert stale_grace_ticks(hz) == round(STALE_GRACE_S * hz)


def test_no_command_while_stale_and_the_run_resumes_within_the_grace():
    st = station()
    cmds = []
    for tick in range(1, 200):
        stale_from = 40 if tick < 40 + st.stale_grace_ticks - 10 else None  # stale for grace - 10 ticks
        reis, hold = arms(tick, stale_from)
        res = st.on_tick(tick, reis, hold, lead)
        assert res.stop is None, (tick, res.stop)
        if res.tool_cmd is not None:
            cmds.append(tick)
    stale_ticks = [t for t in cmds if 40 <= t < 40 + st.stale_grace_ticks - 10]
    assert stale_ticks == []  # nothing written while stale
    assert max(cmds) > 40 + st.stale_grace_ticks  # and commands again afterwards


def test_stale_past_the_grace_stops_the_run_as_stale_naming_the_arm():
    st = station()
    stop_tick = None
    for tick in range(1, 400):
        reis, hold = arms(tick, stale_from=50)
        res = st.on_tick(tick, reis, hold, lead)
        if res.stop is not None:
            stop_tick = tick
            break
    assert stop_tick is not None
    assert res.stop.reason == STOP_STALE and res.stop.detail == "arm1 went stale"
    # the first cycle after grace ticks of staleness (counted from the first stale cycle)
    assert 0 < stop_tick - 50 - st.stale_grace_ticks <= st.cycle_ticks + 1
    assert st.on_tick(stop_tick + 2, *arms(stop_tick + 2), lead).stop is res.stop  # stays stopped


def test_a_fault_stops_before_any_command_and_the_holder_is_commanded_once():
    st = station()
    res = st.on_tick(1, *arms(1), lead)
    assert res.tool_cmd is not None and res.hold_cmd is not None  # gen_hold_robot_wcp: first cycle
    res = st.on_tick(3, *arms(3), lead)
    assert res.tool_cmd is not None and res.hold_cmd is None
    res = st.on_tick(5, *arms(5, fault=FAULT_SERVO), lead)
    assert res.stop is not None and res.stop.reason == STOP_FAULT and res.tool_cmd is None


def test_first_cycle_and_log_ticks_hold_back_the_cycle_and_the_log():
    st = station(first_cycle_tick=10, first_log_tick=4)
    first_cmd = first_log = None
    for tick in range(1, 30):
        res = st.on_tick(tick, *arms(tick), lead)
        if res.tool_cmd is not None and first_cmd is None:
            first_cmd = tick
        if res.log and first_log is None:
            first_log = tick
    assert first_cmd == 10
    assert first_log is not None and first_log >= 4


def test_the_lead_is_read_only_on_a_cycle():
    st = station()
    reads = []

    def counting_lead():
        reads.append(1)
        return INVALID_READING, 0

    for tick in range(1, 61):
        st.on_tick(tick, *arms(tick), counting_lead)
    assert len(reads) == 30  # 30 Hz cycles in one second of 60 Hz ticks
    assert np.isfinite(st.out.travel_mm)
