"""The simulated KAREL controller: 9600-baud pacing both ways, the 6 Hz interpreter, motion."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from droid.kinematics import load_robot
from droid.kinematics.transforms import T_to_pose
from droid.sim.gmf1.controller import KarelController, KarelParams, Motion
from droid.sim.serial_cable import PacedLine
from droid.subunits.gmf1 import karel_wire as kw

MODEL = load_robot("fanuc_s400")
Q0 = [10, 15, 5, 0, 30, 0]


def run(c, t_from, t_to, dt=0.001, feed=()):
    """Advance a controller in world steps, handing it ``feed`` [(t, bytes)] as a host would write
    them; returns [(t, bytes)] of what it transmitted."""
    out = []
    feed = sorted(feed, key=lambda e: e[0])
    i = 0
    n = int(round((t_to - t_from) / dt))
    for k in range(1, n + 1):
        t = t_from + k * dt
        while i < len(feed) and feed[i][0] <= t:
            c.receive(feed[i][1], t - dt)
            i += 1
        c.advance(t)
        b = c.transmit(t)
        if b:
            out.append((t, b))
    return out


def replies(chunks):
    lines = kw.LineSplitter().feed(b"".join(b for _, b in chunks))
    return [kw.parse_reply(ln) for ln in lines]


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 3), st.integers(1, 400)), min_size=1, max_size=12),
       st.sampled_from([0.001, 0.005, 1 / 60]))
def test_line_never_exceeds_960_bytes_a_second(pushes, dt):
    line = PacedLine(9600, capacity_bytes=1 << 20)
    pushes = sorted(pushes)
    released = []  # (time, n)
    t, i = 0.0, 0
    steps = int(6.0 / dt)
    for k in range(1, steps + 1):
        t = k * dt
        while i < len(pushes) and pushes[i][0] <= t:
            line.push(b"x" * pushes[i][1], pushes[i][0])
            i += 1
        data, _ = line.pop_due(t)
        if data:
            released.append((t, len(data)))
    times = np.array([r[0] for r in released])
    counts = np.cumsum([r[1] for r in released])
    for j, t0 in enumerate(times):
        # bytes released in (t0 - 1 s, t0]
        k0 = np.searchsorted(times, t0 - 1.0, side="right")
        n = counts[j] - (counts[k0 - 1] if k0 > 0 else 0)
        assert n <= 960 + (dt * 960 + 1), (t0, n)  # a step may hand out what ended inside it
    assert line.released + line.queued == sum(n for _, n in pushes)
    # the line's own clock: byte k of the run ends at a bit time, 10 bits after the previous
    assert line.released <= 6.0 * 960


def test_line_deadlines_are_absolute_bit_times():
    line = PacedLine(9600)
    line.push(b"a" * 960, 0.0)
    got = sum(len(line.pop_due(k / 1000)[0]) for k in range(1, 1001))
    assert got == 960  # exactly one second of bytes in one second
    assert line.pop_due(1.0)[0] == b""
    line.push(b"b" * 10, 5.0)
    assert len(line.pop_due(5.0 + 9.5 * 10 / 9600)[0]) == 9


def test_incoming_bytes_are_consumed_at_line_rate():
    """A host that writes 30 STAT lines at once: the controller hears them at 960 bytes/s."""
    c = KarelController(MODEL, q0_deg=Q0)
    burst = b"".join(kw.format_stat(i) for i in range(1, 31))
    c.receive(burst, 0.0)
    run(c, 0.0, 0.1)
    assert c.lines == int(0.1 * 960 // len(kw.format_stat(1)))  # only what crossed the line by then
    run(c, 0.1, 2.0)
    assert c.lines == 30


def test_replies_leave_at_line_rate():
    c = KarelController(MODEL, q0_deg=Q0, params=KarelParams(cycle_hz=1000.0, reply_delay_s=0.0))
    chunks = run(c, 0.0, 3.0, feed=[(i * 0.001, kw.format_stat(i)) for i in range(1, 200)])
    per_second = {}
    for t, b in chunks:
        per_second[int((t - 1e-9) // 1)] = per_second.get(int((t - 1e-9) // 1), 0) + len(b)
    assert max(per_second.values()) <= 960
    assert sum(per_second.values()) > 960  # the replies did need more than a second


def test_interpreter_takes_one_line_per_cycle():
    c = KarelController(MODEL, q0_deg=Q0)
    # the second line ends ~8 ms after the first
    rs = replies(run(c, 0.0, 1.0, feed=[(0.0, kw.format_stat(1) + kw.format_stat(2)),
                                        (0.5, kw.format_stat(3))]))
    assert [(r.kind, r.cmd_id) for r in rs] == [(kw.STAT, 1), (kw.BUSY, 2), (kw.STAT, 3)]


def test_flood_is_accepted_at_most_6_a_second():
    c = KarelController(MODEL, q0_deg=Q0)
    feed = [(k / 60, kw.format_stat(k + 1)) for k in range(600)]  # 60 requests a second for 10 s
    rs = replies(run(c, 0.0, 10.5, feed=feed))
    stats = [r for r in rs if r.kind == kw.STAT]
    assert 50 <= len(stats) <= 61
    assert len(rs) == 600  # every line is answered


def test_move_is_acked_and_done_at_its_planned_time():
    c = KarelController(MODEL, q0_deg=Q0)
    pose = T_to_pose(MODEL.fk([0, 10, 10, 0, 40, 20]))
    line = kw.format_move(7, pose, 1.5)
    c.receive(line, 0.0)
    chunks = run(c, 0.0, 5.0)
    rs = replies(chunks)
    assert [r.kind for r in rs] == [kw.ACK, kw.DONE]
    ack = rs[0]
    assert ack.seconds >= 1.5
    t_line = len(line) * 10 / 9600
    t_done_sent = chunks[-1][0]
    # DONE is queued when the move ends and takes ~8 bytes of line time to arrive
    start = t_line + c.p.reply_delay_s
    assert start + ack.seconds < t_done_sent < start + ack.seconds + 0.02
    np.testing.assert_allclose(T_to_pose(MODEL.fk(c.q_deg))[:3], pose[:3], atol=1e-6)


def test_motion_respects_the_speed_limits():
    c = KarelController(MODEL, q0_deg=Q0)
    q_goal = np.array([-60, 40, 60, 90, -60, 120.0])
    T = c.min_duration_s(c.q_deg, q_goal)
    m = Motion(c.q_deg, q_goal, 0.0, T, c.p.ramp_s, 1)
    ts = np.linspace(0, T, 4001)
    q = np.array([m.q_at(t) for t in ts])
    v = np.abs(np.diff(q, axis=0)) / np.diff(ts)[:, None]
    assert np.all(v.max(axis=0) <= MODEL.vmax_deg_s * c.p.joint_speed_fraction * 1.01)
    p = np.array([MODEL.fk(qq)[:3, 3] for qq in q[::40]])
    chord = np.linalg.norm(p[-1] - p[0])
    assert chord / (T - c.p.ramp_s) <= c.p.speed_mm_s * 1.001 or T == pytest.approx(
        np.max(np.abs(q_goal - Q0) / (MODEL.vmax_deg_s * c.p.joint_speed_fraction)) + c.p.ramp_s)
    np.testing.assert_allclose(q[-1], q_goal)
    assert m.fraction(-1) == 0 and m.fraction(T + 1) == 1


def test_move_while_moving_is_busy_and_stat_reports_moving():
    c = KarelController(MODEL, q0_deg=Q0)
    rs = replies(run(c, 0.0, 6.0, feed=[(0.0, kw.format_home(1)), (0.5, kw.format_jmove(2, [0] * 6)),
                                        (1.0, kw.format_stat(3))]))
    kinds = [(r.kind, r.cmd_id) for r in rs]
    assert kinds[:3] == [(kw.ACK, 1), (kw.BUSY, 2), (kw.STAT, 3)]
    assert rs[2].state == kw.MOVING and rs[2].motion_id == 1
    assert kinds[3] == (kw.DONE, 1)
    np.testing.assert_allclose(c.q_deg, 0)


@pytest.mark.parametrize("line, code", [
    (kw.format_move(4, [9000, 0, 0, 0, 0, 0]), kw.ERR_RANGE),       # out of reach
    (kw.format_jmove(4, [0, 0, 0, 0, 170, 0]), kw.ERR_RANGE),       # j5 beyond its limit
    (b"MOVE 4 1 2\r", kw.ERR_SYNTAX),
    (b"Z" * 300 + b"\r", kw.ERR_LONG),
])
def test_bad_requests_are_answered_with_err_and_nothing_moves(line, code):
    c = KarelController(MODEL, q0_deg=Q0)
    c.receive(line, 0.0)
    rs = replies(run(c, 0.0, 1.0))
    assert len(rs) == 1 and rs[0].kind == kw.ERR and rs[0].code == code
    np.testing.assert_allclose(c.q_deg, Q0)


@settings(max_examples=50, deadline=None)
@given(st.binary(max_size=300))
def test_controller_survives_random_bytes(data):
    c = KarelController(MODEL, q0_deg=Q0)
    c.receive(data + b"\r", 0.0)
    rs = replies(run(c, 0.0, 1.0, dt=0.005))
    assert all(r.kind in kw.REPLY_KINDS for r in rs)
    assert c.model.within_limits(c.q_deg)
