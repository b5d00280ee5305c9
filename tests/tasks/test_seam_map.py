"""The seam map of plus mode (issue 12 item 3) and the plus core with a perfect arm:
outlier rejection, the local fit, gaps bridged, a clear stop when the gap is too long."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from droid.tasks.seam.params import SeamParams
from droid.tasks.seam.stops import STOP_END, STOP_LOST
from droid.tasks.seam.cycle import TrackingCycle
from droid.tasks.seam.delay import INVALID_READING
from droid.tasks.seam.seammap import SeamMap, chord_point

sys.path.insert(0, str(Path(__file__).parent))
from test_seam_core import T_HOLD, WRIST, start_pose, straight_seam_reading, tool_offset_mm  # noqa: E402

NORMAL = np.array([0.0, 0.0, -1.0])


def fed(points, rng=None, sigma=0.0):
    m = SeamMap()
    m.seed(points[0], NORMAL, points[1] - points[0])
    for p in points[1:]:
        q = p + (rng.normal(0.0, sigma, 3) * [0, 1, 0.2] if rng is not None else 0.0)
        m.add(q, NORMAL)
    return m


def test_outliers_are_rejected_and_the_fit_holds_the_line():
    rng = np.random.default_rng(3)
    pts = [np.array([x, 0.0, 0.0]) for x in np.arange(100.0, 300.0, 0.5)]
    pts = [np.zeros(3)] + pts
    m = SeamMap()
    m.seed(pts[0], NORMAL, [1.0, 0.0, 0.0])
    for i, p in enumerate(pts[1:]):
        q = p + [0.0, rng.normal(0.0, 0.06), 0.0]
        if i > 40 and i % 10 == 0:
            q = q + [0.0, 5.0, 0.0]  # 10 % spurious points 5 mm off
        m.add(q, NORMAL)
    assert m.rejected >= 30
    ys = [abs(m.fit(s).p[1]) for s in np.arange(130.0, 280.0, 1.0)]
    assert max(ys) <= 0.1
    f = m.fit(200.0)
    assert abs(f.t[0]) == pytest.approx(1.0, abs=1e-3) and np.allclose(f.n, NORMAL, atol=1e-6)


def test_a_real_corner_enters_the_map_after_it_is_confirmed():
    a = np.radians(5.0)
    pts = [np.zeros(3)] + [np.array([x, 0.0, 0.0]) for x in np.arange(100.0, 200.0, 0.5)]
    pts += [np.array([200.0 + u * math.cos(a), u * math.sin(a), 0.0]) for u in np.arange(0.5, 100.0, 0.5)]
    m = fed(pts)
    f = m.fit(m.front_s - 10.0)
    assert math.degrees(math.atan2(f.t[1], f.t[0])) == pytest.approx(5.0, abs=0.3)
    assert m.rejected == 0


def test_the_fit_gives_the_curvature_of_an_arc():
    R = 200.0
    pts = [np.array([-100.0, 0.0, 0.0])] + [np.array([R * math.sin(u / R), R - R * math.cos(u / R), 0.0])
                                            for u in np.arange(0.0, 150.0, 0.5)]
    m = fed(pts, np.random.default_rng(1), 0.05)
    f = m.fit(m.front_s - 40.0, wide=4.0)  # the curvature wants a longer window than position
    assert 1.0 / np.linalg.norm(f.k) == pytest.approx(R, rel=0.25)
    assert abs(np.linalg.norm(m.fit(m.front_s - 40.0).p - [0.0, R, 0.0]) - R) <= 0.05


def test_a_gap_is_bridged_and_beyond_the_bridge_there_is_no_map():
    pts = [np.zeros(3)] + [np.array([x, 0.0, 0.0]) for x in np.arange(100.0, 150.0, 0.5)]
    pts += [np.array([x, 0.0, 0.0]) for x in np.arange(170.0, 200.0, 0.5)]  # 20 mm without readings
    m = fed(pts)
    assert abs(m.fit(160.0).p[1]) < 1e-6 and m.fit(160.0).p[0] == pytest.approx(160.0, abs=0.1)
    assert m.fit(m.front_s + 29.0) is not None  # extrapolated
    assert m.fit(m.front_s + 31.0) is None  # too far: the tracker stops
    assert chord_point(m, 100.0, m.fit(100.0).p, 50.0).p[0] == pytest.approx(150.0, abs=0.2)



def test_on_a_tight_arc_the_sensor_aims_at_the_farthest_mapped_seam_when_no_chord_reaches():
    """A 90 degree arc of R25 mapped to its end, the tool 60 mm before the arc: the whole map --
    its extrapolation with the arc's curvature bending back -- lies nearer than 100 mm.  Plain
    ``chord_point`` has no answer (plus mode used to aim along the tool's tangent then and swung
    the sensor off the seam); ``farthest`` gives the map point farthest from the tool, at least as
    far as the arc's end, not behind it."""
    R = 25.0
    pts = [np.array([x, 0.0, 0.0]) for x in np.arange(0.0, 125.0, 0.5)]
    pts += [np.array([125.0 + R * math.sin(u / R), R - R * math.cos(u / R), 0.0])
            for u in np.arange(0.5, R * math.pi / 2 + 0.01, 0.5)]
    m = fed(pts)
    end = np.array([150.0, 25.0, 0.0])
    assert np.linalg.norm(m.fit(m.front_s).p - end) <= 0.5
    s0 = 65.0
    p0 = m.fit(s0).p
    assert chord_point(m, s0, p0, 100.0) is None
    far = chord_point(m, s0, p0, 100.0, farthest=True)
    assert far is not None and far.s_mm >= m.front_s - 1.0
    assert np.linalg.norm(far.p - p0) >= np.linalg.norm(end - p0) - 0.5
    # where a chord does reach, ``farthest`` changes nothing
    assert chord_point(m, 60.0, m.fit(60.0).p, 80.0, farthest=True).s_mm == pytest.approx(
        chord_point(m, 60.0, m.fit(60.0).p, 80.0).s_mm, abs=1e-9)


def perfect_plus(sensor, cycles, **kw):
    """The plus core in a closed loop with a perfect arm (at the command one cycle later)."""
    cyc = TrackingCycle(SeamParams(16.0, mode="plus", **kw), WRIST.T_wcp_tool, WRIST.T_wcp_sensor)
    T = start_pose()
    outs = []
    for k in range(cycles):
        tick = 2 * (k + 1)
        cyc.remember(tick - 1, T, tick - 1, T_HOLD)
        cyc.remember(tick, T, tick, T_HOLD)
        out = cyc.step(T_HOLD, T, tick, sensor(T @ WRIST.T_wcp_sensor), tick + 1)
        outs.append((out, T))
        if out.stop is not None:
            break
        T = out.tool_cmd
    return cyc, outs


def test_plus_converges_onto_an_offset_seam_at_the_commanded_speed():
    cyc, outs = perfect_plus(lambda T: straight_seam_reading(T, offset_mm=3.0), 2000, length_mm=300.0)
    assert outs[-1][0].stop.reason == STOP_END
    assert tool_offset_mm(outs[-1][1]) == pytest.approx(3.0, abs=0.05)
    steps = np.diff([o.travel_mm for o, _ in outs[100:-1]])
    assert np.mean(steps) == pytest.approx(16.0 / 30.0, rel=0.02)


def test_plus_stops_clearly_when_the_map_runs_out():
    """Readings stop after 150 mm of tool travel; with the lost-cycles rule out of the way the
    map's bridge ends the run: 'seam lost', no command beyond the bridged gap."""
    def sensor(T):
        return straight_seam_reading(T) if T[0, 3] < 480.0 else INVALID_READING
    cyc, outs = perfect_plus(sensor, 3000, lost_cycles=10_000, gap_mm=20.0)
    last = outs[-1][0]
    assert last.stop.reason == STOP_LOST and "no seam mapped" in last.stop.detail
    assert cyc.core.s_cmd <= cyc.core.map.front_s + 20.0


def _biased_run(bias_mm, cycles=900):
    """The perfect arm, but it settles ``bias_mm`` deeper along the tool axis than commanded
    (a sag its encoders see): the Status shows where it is."""
    from droid.kinematics.transforms import trans

    cyc = TrackingCycle(SeamParams(16.0, mode="plus", length_mm=400.0), WRIST.T_wcp_tool, WRIST.T_wcp_sensor)
    T = start_pose()
    sag = WRIST.T_wcp_tool @ trans(bias_mm, 0.0, 0.0) @ np.linalg.inv(WRIST.T_wcp_tool)
    out = None
    for k in range(cycles):
        tick = 2 * (k + 1)
        cyc.remember(tick - 1, T, tick - 1, T_HOLD)
        cyc.remember(tick, T, tick, T_HOLD)
        out = cyc.step(T_HOLD, T, tick, straight_seam_reading(T @ WRIST.T_wcp_sensor), tick + 1)
        if out.stop is not None:
            break
        T = out.tool_cmd @ sag
    tool_z = float((T @ WRIST.T_wcp_tool)[2, 3])  # the seam lies at z = 0, the tool axis is -z
    return tool_z, cyc


def test_plus_integral_action_removes_a_steady_depth_error(monkeypatch):
    z, cyc = _biased_run(1.0)
    assert abs(z) <= 0.05, z  # on the seam in depth despite the 1 mm sag
    assert cyc.core.depth_bias_mm == pytest.approx(1.0, abs=0.05)
    import droid.tasks.seam.plus as plus

    monkeypatch.setattr(plus, "DEPTH_KI", 0.0)
    z_off, _ = _biased_run(1.0)
    assert abs(z_off) >= 0.9  # without it the sag stays
