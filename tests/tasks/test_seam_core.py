"""The seam-tracking core (thesis §5.1-5.5, §6.2.5) without processes or a simulated world.

A "perfect arm" follows every Reis command exactly and a geometric lead sensor
reads a straight seam, so the core's own behaviour is what is tested: the
invalid-data rule, the transport-delay buffer, the stop reasons, convergence.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.kinematics import load_robot
from droid.kinematics.transforms import trans
from droid.tasks.seam.core import SeamTracker
from droid.tasks.seam.params import PHASE_DEAD_ZONE, SeamParams
from droid.tasks.seam.stops import STOP_END, STOP_LOST, STOP_UNREACHABLE
from droid.tasks.seam.delay import (DELAY_DELAYED, DELAY_OFF, DELAY_ZEROED, INVALID_READING, ZERO_READING,
                                    Reading, TransportDelay)
from droid.brain.cell.cell_layout import load_layout

LAYOUT = load_layout()
WRIST = LAYOUT.wrist("standard")
T_HOLD = LAYOUT.start_poses("i")[1]


def straight_seam_reading(T_global_S, offset_mm=0.0, depth_mm=0.0) -> Reading:
    """A straight seam along the global line through (0, offset, -depth) in x, surface normal +z:
    where the sensor's laser sheet (its x-y plane) crosses it, in the sensor frame."""
    o, x, y, z = T_global_S[:3, 3], T_global_S[:3, 0], T_global_S[:3, 1], T_global_S[:3, 2]
    p0, d = np.array([0.0, offset_mm, -depth_mm]), np.array([1.0, 0.0, 0.0])
    u = float(np.dot(o - p0, z) / np.dot(d, z))
    p = p0 + u * d - o
    return Reading(float(np.dot(p, x)), float(np.dot(p, y)), 0.0, True)


def start_pose() -> np.ndarray:
    """Reis WCP with its tool frame on the seam line (global +x), tool axis down, 100 mm before x = 0."""
    T_tool = np.array([[0.0, 0.0, 1.0, -100.0], [0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0, 0, 0, 1.0]])
    return T_tool @ np.linalg.inv(WRIST.T_wcp_tool)


def perfect_run(params: SeamParams, cycles: int, sensor=straight_seam_reading, model=None):
    core = SeamTracker(params, WRIST.T_wcp_tool, WRIST.T_wcp_sensor, model)
    T = start_pose()
    outs = []
    for _ in range(cycles):
        out = core.step(T_HOLD, T, sensor(T @ WRIST.T_wcp_sensor))
        outs.append((out, T))
        if out.stop is not None:
            break
        T = out.tool_cmd  # the perfect arm is where it was told to be one cycle later
    return core, outs


def tool_offset_mm(T_reis) -> float:
    return float((T_reis @ WRIST.T_wcp_tool)[1, 3])


# -- the transport-delay buffer (§6.2.5) -------------------------------------------------

def test_delay_passes_through_until_the_trigger_then_zeroes_then_delays():
    d = TransportDelay(cycles=3, at_mm=10.0)
    readings = [Reading(float(i), 0.0, 0.0, True) for i in range(12)]
    travel = [0, 5, 9.9, 10, 11, 12, 13, 14, 15, 16, 17, 18]
    got = [d.filter(r, t) for r, t in zip(readings, travel)]
    assert [s for _, s in got[:3]] == [DELAY_OFF] * 3 and [r.x_mm for r, _ in got[:3]] == [0, 1, 2]
    assert [s for _, s in got[3:6]] == [DELAY_ZEROED] * 3 and all(r == ZERO_READING for r, _ in got[3:6])
    assert [s for _, s in got[6:]] == [DELAY_DELAYED] * 6
    assert [r.x_mm for r, _ in got[6:]] == [3, 4, 5, 6, 7, 8]  # the readings of 3 cycles ago
    assert d.triggered_at_cycle == 3


def test_no_delay_is_a_pass_through_and_bad_delays_are_refused():
    d = TransportDelay(0)
    r = Reading(1.0, 2.0, 0.1, True)
    assert d.filter(r, 1e6) == (r, DELAY_OFF)
    with pytest.raises(ValueError):
        TransportDelay(-1)
    with pytest.raises(ValueError):
        TransportDelay(2, at_mm=-1.0)


@pytest.mark.parametrize("kw", [dict(speed_mm_s=0), dict(speed_mm_s=math.nan), dict(speed_mm_s=8, yaw_gain=math.inf),
                                dict(speed_mm_s=8, length_mm=0), dict(speed_mm_s=8, delay_cycles=-2),
                                dict(speed_mm_s=8, lost_cycles=0), dict(speed_mm_s=8, dead_zone_cycles=1.5),
                                dict(speed_mm_s=900.0), dict(speed_mm_s=8, mode="fastest"),
                                dict(speed_mm_s=8, accel_mm_s2=0.0), dict(speed_mm_s=8, gap_mm=-1.0)])
def test_bad_parameters_are_refused(kw):
    with pytest.raises(ValueError):
        SeamParams(**kw)


# -- the core in a closed loop with a perfect arm --------------------------------------------

@pytest.mark.parametrize("mode", ["thesis", "listing"])
def test_a_lateral_offset_is_tracked_out_on_a_straight_seam(mode):
    """The seam lies 3 mm to the left of the start line: after the initial section the
    tool converges onto it (the perfect arm isolates the core's geometry, eq. 5.1-5.11)."""
    params = SeamParams(speed_mm_s=16.0, length_mm=400.0, mode=mode)
    core, outs = perfect_run(params, 2000, sensor=lambda T: straight_seam_reading(T, offset_mm=3.0))
    assert outs[-1][0].stop is not None and outs[-1][0].stop.reason == STOP_END
    assert outs[0][0].phase == PHASE_DEAD_ZONE
    final_tool = tool_offset_mm(outs[-1][1])
    assert final_tool == pytest.approx(3.0, abs=0.3)
    # the travel per cycle is the commanded speed: vel = speed / 30 Hz
    steps = np.diff([o.travel_mm for o, _ in outs[40:-1]])
    if mode == "listing":  # every cycle's move is vel, but the listing's patch index steps the tool
        # back now and then; the run length (TRAVEL_CHORD_MM chords) counts only the net progress
        moves = np.linalg.norm(np.diff([(T @ WRIST.T_wcp_tool)[:3, 3] for _, T in outs[40:-1]], axis=0), axis=1)
        assert np.allclose(moves, 16.0 / 30.0, rtol=0.05)
        net = np.diff([float((T @ WRIST.T_wcp_tool)[0, 3]) for _, T in outs[40:-1]])
        assert np.mean(steps) == pytest.approx(np.mean(net), rel=0.01)
        assert np.mean(net) < 0.97 * 16.0 / 30.0  # (the per-cycle sum counted the steps back as travel)
    else:  # vel along the patch from the tool's projection: shorter where the tool cuts a patch vertex
        assert np.mean(steps) == pytest.approx(16.0 / 30.0, rel=0.01)
        assert np.mean(np.abs(steps / (16.0 / 30.0) - 1.0) <= 0.05) >= 0.99


def test_invalid_data_means_zeros_the_tracker_goes_straight_on():
    """§6.2.5: invalid data -> x, y, roll = 0: the corrections vanish and the run continues
    straight until the seam counts as lost."""
    params = SeamParams(speed_mm_s=8.0, dead_zone_cycles=5, lost_cycles=12)
    _, outs = perfect_run(params, 200, sensor=lambda T: INVALID_READING)
    moving = [o for o, _ in outs if o.stop is None]
    assert len(moving) == 5 + 12  # the dead zone, lost_cycles invalid cycles; the next one stops
    assert all(o.yaw_rad == 0.0 and o.pitch_rad == 0.0 for o in moving)
    ys = [tool_offset_mm(o.tool_cmd) for o in moving]
    assert np.allclose(ys, 0.0, atol=1e-9)  # straight on along the start line
    last = outs[-1][0]
    assert last.stop.reason == STOP_LOST and last.tool_cmd is None and last.hold_cmd is None


def test_unreachable_command_stops_the_run_before_it_is_sent():
    far = load_robot("reis_v15").with_base(trans(5000.0, 0.0, 0.0))  # the Reis base 5 m away
    params = SeamParams(speed_mm_s=8.0)
    core, outs = perfect_run(params, 5, model=far)
    out = outs[-1][0]
    assert out.stop.reason == STOP_UNREACHABLE and out.tool_cmd is None
    # stopped stays stopped
    again = core.step(T_HOLD, start_pose(), ZERO_READING)
    assert again.stop is out.stop and again.tool_cmd is None


def test_the_holder_is_told_to_hold_the_pose_it_started_with():
    params = SeamParams(speed_mm_s=8.0, length_mm=50.0)
    _, outs = perfect_run(params, 200)
    holds = [o.hold_cmd for o, _ in outs if o.hold_cmd is not None]
    assert holds and all(np.array_equal(h, T_HOLD) for h in holds)


def test_a_transport_delay_zeroes_then_delays_the_readings_the_core_uses():
    params = SeamParams(speed_mm_s=16.0, length_mm=300.0, delay_cycles=6, delay_at_mm=150.0)
    _, outs = perfect_run(params, 2000, sensor=lambda T: straight_seam_reading(T, offset_mm=2.0))
    states = [o.delay_state for o, _ in outs if o.stop is None]
    first = states.index(DELAY_ZEROED)
    assert states[:first] == [DELAY_OFF] * first
    assert states[first:first + 6] == [DELAY_ZEROED] * 6 and set(states[first + 6:]) == {DELAY_DELAYED}
    assert outs[first][0].travel_mm >= 150.0 > outs[first - 1][0].travel_mm
    zeroed = [o for o, _ in outs[first:first + 6]]
    assert all(o.yaw_rad == 0.0 and o.pitch_rad == 0.0 for o in zeroed)  # zero data: no correction
    assert outs[-1][0].stop.reason == STOP_END


def test_a_tool_that_jumps_stops_the_run_as_a_runaway():
    """The runaway guard (an addition): the arm reported 15 mm from where it was one cycle ago
    (after the dead zone: during it the arm may still settle from its start move)."""
    from droid.tasks.seam.stops import STOP_RUNAWAY

    params = SeamParams(speed_mm_s=16.0, dead_zone_cycles=0)
    core = SeamTracker(params, WRIST.T_wcp_tool, WRIST.T_wcp_sensor)
    T = start_pose()
    out = core.step(T_HOLD, T, straight_seam_reading(T @ WRIST.T_wcp_sensor))
    T = out.tool_cmd
    assert core.step(T_HOLD, T, straight_seam_reading(T @ WRIST.T_wcp_sensor)).stop is None
    jumped = trans(0.0, 15.0, 0.0) @ T
    out = core.step(T_HOLD, jumped, straight_seam_reading(jumped @ WRIST.T_wcp_sensor))
    assert out.stop is not None and out.stop.reason == STOP_RUNAWAY and out.tool_cmd is None
    assert "15.5 mm in 3 cycles (limit 10.0 mm)" in out.stop.detail
    settling = SeamTracker(SeamParams(speed_mm_s=16.0, dead_zone_cycles=5), WRIST.T_wcp_tool, WRIST.T_wcp_sensor)
    settling.step(T_HOLD, start_pose(), ZERO_READING)
    assert settling.step(T_HOLD, trans(0.0, 15.0, 0.0) @ start_pose(), ZERO_READING).stop is None
    off = SeamTracker(SeamParams(speed_mm_s=16.0, dead_zone_cycles=0, runaway_factor=0.0), WRIST.T_wcp_tool,
                      WRIST.T_wcp_sensor)
    off.step(T_HOLD, start_pose(), ZERO_READING)
    assert off.step(T_HOLD, trans(0.0, 15.0, 0.0) @ start_pose(), ZERO_READING).stop is None


def run_with_a_shaking_tool(core) -> float:
    """Run a tracker core along the straight seam from the start pose while the *measured* tool
    point shakes 0.1 mm across the seam every cycle (stick-slip, drive compliance on the full
    arm) until it stops; asserts it stopped at the end of its run and returns how far the
    commanded tool advanced along the seam [mm]."""
    T = start_pose()
    x0 = float((T @ WRIST.T_wcp_tool)[0, 3])
    out = None
    for k in range(3000):
        T_meas = T.copy()
        T_meas[1, 3] += 0.1 * (1 if k % 2 else -1)
        out = core.step(T_HOLD, T_meas, straight_seam_reading(T_meas @ WRIST.T_wcp_sensor))
        if out.stop is not None:
            break
        T = out.tool_cmd
    assert out.stop is not None and out.stop.reason == STOP_END
    return float((T @ WRIST.T_wcp_tool)[0, 3]) - x0  # along the seam (global +x)


def test_plus_mode_measures_its_run_length_along_the_seam_map_not_the_jittery_tool_path():
    """Plus mode's run length is the tool's progress along the seam map (its foot on the map),
    not the summed path of the measured tool point: an arm whose tool point shakes 0.1 mm across
    the seam every cycle (stick-slip, drive compliance) adds ~0.2 mm of path a cycle to the sum
    at 4 mm/s (0.13 mm a cycle along the seam) -- the run would end far too early."""
    from droid.tasks.seam.plus import PlusTracker

    params = SeamParams(speed_mm_s=4.0, length_mm=40.0, mode="plus")
    core = PlusTracker(params, WRIST.T_wcp_tool, WRIST.T_wcp_sensor)
    advanced = run_with_a_shaking_tool(core)
    assert advanced == pytest.approx(40.0, abs=1.0)
    assert core.travel.path_mm >= 1.5 * advanced  # the summed path ran far ahead: it is not the measure


@pytest.mark.parametrize("mode", ["thesis", "listing"])
def test_thesis_modes_measure_their_run_length_in_chords_not_the_jittery_per_cycle_path(mode):
    """Thesis and listing modes end their run at its length although the measured tool point
    shakes 0.1 mm across the seam every cycle (stick-slip on the full arm): the run length is the
    tool path in TRAVEL_CHORD_MM chords (``TravelGuard``), which the shake hardly lengthens, not
    the per-cycle sum, which it makes run far ahead (the full arm's 700 mm trials ended at
    276-602 mm with it)."""
    params = SeamParams(speed_mm_s=4.0, length_mm=40.0, mode=mode)
    core = SeamTracker(params, WRIST.T_wcp_tool, WRIST.T_wcp_sensor)
    advanced = run_with_a_shaking_tool(core)
    assert advanced == pytest.approx(40.0, abs=1.0)
    assert core.s.travel.path_mm >= 1.2 * advanced  # the per-cycle sum ran ahead: it is not the measure


def test_chord_travel_follows_an_arc_and_never_decreases():
    """The chord measure of a tool point moving along a 25 mm radius arc, with 0.2 mm of jitter
    along and across the path, stays within 1 % of the arc length and never decreases."""
    from droid.tasks.seam.guard import TravelGuard

    guard = TravelGuard(SeamParams(speed_mm_s=4.0, length_mm=1e9))
    rng = np.random.default_rng(3)
    last = 0.0
    for k in range(1200):  # 0.1 mm a cycle: 120 mm of arc, over 270 degrees
        a = k * 0.1 / 25.0
        p = np.array([25.0 * math.sin(a), 25.0 * (1 - math.cos(a)), 0.0]) + rng.uniform(-0.2, 0.2, 3)
        guard.step(p, 1.0, guard_runaway=False)
        assert guard.travel_mm >= last
        last = guard.travel_mm
    assert last == pytest.approx(119.9, rel=0.01)
    assert guard.path_mm > 2.0 * last  # the per-cycle sum: more than twice the arc


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["push", "keep"]),
                          st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3), st.integers(0, 12)),
                max_size=60))
def test_the_patch_array_holds_the_same_values_as_its_points(ops):
    """SeamPatch keeps its float64 array beside its points (issue 28 item 2): after any pushes and
    cuts it is, bit for bit, what converting the points would give -- the thesis-mode search reads
    the array instead of converting the list each cycle; so are its segments' vectors and
    divisors, computed once per segment."""
    from droid.tasks.seam.patch import SeamPatch

    class Tight(SeamPatch):  # reallocates on almost every push
        __slots__ = ()
        ROOM_ROWS = 1

    for patch in (SeamPatch([(0.5, -1.25, 3.0)]), Tight([(0.5, -1.25, 3.0)])):
        _check_patch_ops(patch, ops)


def _check_patch_ops(patch, ops) -> None:
    for op, point, n in ops:
        if op == "push":
            patch.push_front(point)
        else:
            patch.keep(n)
        want = np.asarray(patch.points, float).reshape(-1, 3)
        assert patch.array.shape == want.shape and patch.array.tobytes() == want.tobytes()
        assert len(patch) == len(patch.points) and (not len(patch) or patch[0] == patch.points[0])
        if len(patch) > 1:  # the segments' numbers: what the search computed from the array each cycle
            ab, den, ok = patch.segments()
            want_ab = want[:-1] - want[1:]
            l2 = np.einsum("ij,ij->i", want_ab, want_ab)
            assert ab.tobytes() == want_ab.tobytes() and ok.tolist() == (l2 > 1e-18).tolist()
            assert den.tobytes() == np.where(l2 > 1e-18, l2, 1.0).tobytes()
