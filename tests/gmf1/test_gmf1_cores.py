"""The serial and encoder cores on their own: random replies, time-outs, the homing handshake."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from droid.brain.db.layouts import (CARTSPACE, CMD_FAILED, CMD_OK, HOME_MODE, HOMED, JOG_MODE, NORMAL_MODE, OFF)
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.subunits.gmf1 import karel_wire as kw
from droid.subunits.gmf1.encoder_core import EncoderCore, HomeView, signed24, wants_zeroing
from droid.subunits.gmf1.serial_core import (CLOSED, IDLE, MOVING, PROBING, WAIT_ACK, CommandSnapshot,
                                             SerialCore, StatusView)

MODEL = load_robot("fanuc_s400").with_base(pose_to_T(2000, 0, 0, 180, 0, 0))
HOMED_VIEW = StatusView(True, np.zeros(6, np.int64))
T_TARGET = MODEL.fk([0, 10, 10, 0, 40, 20])


def cmd(cmd_id, mode=NORMAL_MODE, coord=CARTSPACE, T=T_TARGET, ticks=60):
    return CommandSnapshot(cmd_id, mode, coord, np.asarray(T, float), ticks, ticks, np.zeros(6, np.int64))


def opened_core():
    """A core with its port open and its first probe answered (IDLE)."""
    c = SerialCore(MODEL)
    c.step(1, cmd(0), HOMED_VIEW, b"", False)
    out = c.step(2, cmd(0), HOMED_VIEW, b"", True)
    assert out.tx.startswith(b"STAT ")
    pid = kw.parse_request(out.tx[:-1]).cmd_id
    out = c.step(3, cmd(0), HOMED_VIEW, kw.format_reply(kw.Reply(kw.STAT, pid, state=kw.IDLE)), True)
    assert c.state == IDLE and not out.fault
    return c


def test_a_cart_command_is_sent_in_the_base_frame_and_followed_to_done():
    c = opened_core()
    out = c.step(20, cmd(1), HOMED_VIEW, b"", True)
    req = kw.parse_request(out.tx[:-1])
    assert req.verb == kw.MOVE and req.cmd_id == 1 and req.duration_s == pytest.approx(1.0)
    T_base = MODEL.base.copy()
    local = np.linalg.inv(T_base) @ T_TARGET
    np.testing.assert_allclose(req.values[:3], local[:3, 3], atol=5e-4)
    assert out.fields["cmd_id"] == 1 and out.fields["cmd_result"] == CMD_OK and out.fields["busy"] == 60
    assert c.state == WAIT_ACK
    out = c.step(26, cmd(1), HOMED_VIEW, b"ACK 1 2.000\r\n", True)
    assert c.state == MOVING and out.fields["busy"] == 120
    out = c.step(86, cmd(1), HOMED_VIEW, b"", True)
    assert out.fields["busy"] == 60
    out = c.step(200, cmd(1), HOMED_VIEW, b"DONE 1\r\n", True)
    assert c.state == IDLE and out.fields["busy"] == 0 and out.fields["cmd_result"] == CMD_OK
    assert c.completed == 1


def test_off_mode_and_repeated_ids_send_nothing():
    c = opened_core()
    assert c.step(20, cmd(1, mode=OFF), HOMED_VIEW, b"", True).tx == b""
    c.step(21, cmd(2), HOMED_VIEW, b"", True)
    assert c.step(60, cmd(2), HOMED_VIEW, b"", True).tx == b""  # same id: nothing new


def test_the_first_command_seen_is_not_replayed():
    c = SerialCore(MODEL)
    c.step(1, cmd(7), HOMED_VIEW, b"", False)
    assert c.last_seen == 7 and c.pending is None


def test_the_first_command_seen_is_not_replayed_if_status_answers_it():
    c = SerialCore(MODEL)
    c.step(1, cmd(7), StatusView(True, np.zeros(6, np.int64), 7), b"", False)
    assert c.last_seen == 7 and c.pending is None and c.dropped == 0
    c = SerialCore(MODEL)
    c.step(1, cmd(0, mode=JOG_MODE), StatusView(False, np.zeros(6, np.int64), 0), b"", False)
    assert c.last_seen == 0 and c.pending is None  # the safe start values: no command


def test_the_first_command_seen_is_taken_if_no_one_answered_it():
    """Tables 3.1-3.2: executed or refused, never lost (written before the first tick, or
    pending in a run that died)."""
    c = SerialCore(MODEL)
    view = StatusView(False, np.zeros(6, np.int64), 0)
    c.step(1, cmd(1, mode=HOME_MODE), view, b"", False)
    assert c.last_seen == 1 and c.pending is not None and c.dropped == 0
    assert c.step(2, cmd(1, mode=HOME_MODE), view, b"", True).tx.startswith(b"STAT ")  # the link first
    pid = c.probe_id
    out = c.step(3, cmd(1, mode=HOME_MODE), view, kw.format_reply(kw.Reply(kw.STAT, pid, state=kw.IDLE)), True)
    assert out.tx == b"" and c.state == IDLE  # the interpreter's cycle of the probe has not passed
    tick = 3
    while not out.tx:
        tick += 1
        out = c.step(tick, cmd(1, mode=HOME_MODE), view, b"", True)
    assert out.tx == b"HOME 1\r" and out.fields["cmd_id"] == 1 and c.sent == 1


def test_no_reply_means_fault_probe_and_eventually_reopen():
    c = opened_core()
    c.step(20, cmd(1), HOMED_VIEW, b"", True)
    tick = 21
    reopened = False
    faults = []
    for tick in range(21, 2000):
        out = c.step(tick, cmd(1), HOMED_VIEW, b"", not reopened and c.state != CLOSED)
        faults.append(out.fault)
        if out.close_port:
            reopened = True
            break
    assert reopened and c.timeouts >= 3 and c.probes >= 3
    assert faults[-1] and c.state == CLOSED
    assert c.flight is not None  # the command is remembered until the controller says what happened


def test_jog_and_not_homed_are_refused():
    c = opened_core()
    out = c.step(20, cmd(1, mode=JOG_MODE), HOMED_VIEW, b"", True)
    assert out.tx == b"" and out.fields["cmd_result"] != CMD_OK and c.refused == 1
    out = c.step(40, cmd(2), StatusView(False, np.zeros(6)), b"", True)
    assert out.tx == b"" and c.refused == 2


def test_home_clears_homed():
    c = opened_core()
    out = c.step(20, cmd(1, mode=HOME_MODE), StatusView(False, np.zeros(6)), b"", True)
    assert out.tx == b"HOME 1\r" and out.fields["homed"] == 0 and out.fields["cmd_mode"] == HOME_MODE


def test_a_late_done_after_a_timeout_turns_the_result_back_to_ok():
    c = opened_core()
    c.step(20, cmd(1), HOMED_VIEW, b"", True)
    c.step(25, cmd(1), HOMED_VIEW, b"ACK 1 0.500\r\n", True)
    tick = 25
    while c.flight is not None and not c.flight.failed:
        tick += 1
        out = c.step(tick, cmd(1), HOMED_VIEW, b"", True)
    assert out.fields["cmd_result"] == CMD_FAILED and c.state == PROBING
    out = c.step(tick + 1, cmd(1), HOMED_VIEW, b"DONE 1\r\n", True)
    assert c.flight is None and c.state == IDLE and not out.fault and b"MOVE" not in out.tx
    assert out.fields["cmd_result"] == CMD_OK and out.fields["busy"] == 0 and c.late == 1


def test_a_failed_command_that_never_arrived_is_not_sent_late():
    c = opened_core()
    c.step(20, cmd(1), HOMED_VIEW, b"", True)
    tick = 20
    while c.flight is None or not c.flight.failed:
        tick += 1
        out = c.step(tick, cmd(1), HOMED_VIEW, b"", tick < 400)
        if tick > 2000:
            raise AssertionError("never failed")
    # reopen and answer the probe: the controller never saw command 1
    while True:
        tick += 1
        out = c.step(tick, cmd(1), HOMED_VIEW, b"", True)
        if out.tx.startswith(b"STAT"):
            pid = kw.parse_request(out.tx[:-1]).cmd_id
            break
    out = c.step(tick + 3, cmd(1), HOMED_VIEW,
                 kw.format_reply(kw.Reply(kw.STAT, pid, state=kw.IDLE, motion_id=0)), True)
    assert c.state == IDLE and c.flight is None and c.pending is None
    for t in range(tick + 4, tick + 100):
        assert c.step(t, cmd(1), HOMED_VIEW, b"", True).tx == b""


def test_busy_answers_widen_the_gap_between_lines():
    c = opened_core()
    c.step(20, cmd(1), HOMED_VIEW, b"", True)
    sends = [20]
    tick = 20
    for _ in range(4):  # the controller answers BUSY four times
        c.step(tick + 3, cmd(1), HOMED_VIEW, b"BUSY 1\r\n", True)
        tick += 3
        while True:
            tick += 1
            if c.step(tick, cmd(1), HOMED_VIEW, b"", True).tx:
                sends.append(tick)
                break
    gaps = [b - a for a, b in zip(sends, sends[1:])]
    assert gaps == sorted(gaps) and gaps[-1] > gaps[0]
    assert c.busy_rejects == 4 and c.sent == 5


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.binary(max_size=40), st.booleans(), st.integers(0, 5)), max_size=60))
def test_serial_core_takes_any_replies(script):
    """Random reply bytes, ports that come and go, new commands: the core never raises and its
    outputs stay within their ranges."""
    c = SerialCore(MODEL)
    tick = 0
    cmd_id = 0
    for data, port, new in script:
        tick += 1 + new
        if new == 5:
            cmd_id += 1
        out = c.step(tick, cmd(cmd_id, mode=HOME_MODE if cmd_id % 3 == 0 else NORMAL_MODE), HOMED_VIEW,
                     data, port)
        assert out.fields.get("busy", 0) >= 0
        assert c.state in (CLOSED, PROBING, IDLE, WAIT_ACK, MOVING)
        for ln in kw.LineSplitter().feed(out.tx):
            kw.parse_request(ln)  # whatever the core sends follows the grammar
        if not port:
            assert out.fault


# -- encoder core --------------------------------------------------------------------------
HOME_DONE = HomeView(HOME_MODE, 0, CMD_OK, 0)
IDLE_HOMED = HomeView(NORMAL_MODE, 0, CMD_OK, HOMED)


def test_signed24():
    np.testing.assert_array_equal(signed24([0, 1, (1 << 23) - 1, 1 << 23, (1 << 24) - 1]),
                                  [0, 1, (1 << 23) - 1, -(1 << 23), -1])


@given(st.lists(st.integers(-100000, 100000), min_size=1, max_size=50), st.integers(0, (1 << 24) - 1))
def test_extension_across_the_24_bit_wrap(steps, start):
    core = EncoderCore(MODEL)
    true = np.full(6, start, np.int64)
    core.step(true & 0xFFFFFF, np.zeros(6), IDLE_HOMED)
    first = core.extended.copy()
    for d in steps:
        true = true + d
        core.step(true & 0xFFFFFF, np.zeros(6), IDLE_HOMED)
    np.testing.assert_array_equal(core.extended - first, true - start)


def test_homing_handshake_zeroes_once():
    core = EncoderCore(MODEL)
    raw = np.array([5, 6, 7, 8, 9, 10]) + 1000
    assert wants_zeroing(HOME_DONE) and not wants_zeroing(IDLE_HOMED)
    assert not wants_zeroing(HomeView(HOME_MODE, 3, CMD_OK, 0))  # still moving
    assert not wants_zeroing(HomeView(HOME_MODE, 0, CMD_FAILED, 0))  # the HOME failed
    out = core.step(raw, np.zeros(6), HOME_DONE)
    assert out.reset and "x" not in out.fields
    out = core.step(raw, np.zeros(6), HOME_DONE)  # the cards have not executed it yet
    assert not out.reset and "homed" not in out.fields
    out = core.step(np.zeros(6), np.ones(6), HOME_DONE)
    assert out.fields["homed"] == HOMED and np.all(out.fields["encoder_pos"] == 0)
    np.testing.assert_allclose([out.fields["x"], out.fields["y"], out.fields["z"]],
                               MODEL.fk(np.zeros(6))[:3, 3])
    out = core.step(np.zeros(6), np.ones(6), IDLE_HOMED)
    assert not out.reset and core.resets == 1 and core.homings == 1


def test_reset_that_never_happens_is_a_fault_and_is_retried():
    core = EncoderCore(MODEL, rate_hz=120, reset_timeout_s=0.5, retry_s=1.0)
    resets = 0
    faults = []
    for _ in range(400):
        out = core.step(np.zeros(6), np.zeros(6), HOME_DONE)
        resets += out.reset
        faults.append(out.fault)
    assert any(faults) and resets >= 2 and core.homings == 0


def test_no_pose_before_homing():
    core = EncoderCore(MODEL)
    out = core.step(np.full(6, 123), np.zeros(6), HomeView(OFF, 0, CMD_OK, 0))
    assert "x" not in out.fields and np.all(out.fields["encoder_pos"] == 123)


def test_a_garbled_line_is_a_visible_fault_even_when_good_lines_follow():
    c = opened_core()
    out = c.step(10, cmd(0), HOMED_VIEW, b"ST@T ??\r\nBUSY 99\r\n", True)
    assert out.fault and c.garbled == 1
    out = c.step(11, cmd(0), HOMED_VIEW, b"", True)
    assert out.fault  # until the next well-formed reply (a probe is on its way)
    pid = kw.parse_request(out.tx[:-1]).cmd_id if out.tx else None
    tick = 11
    while pid is None:
        tick += 1
        out = c.step(tick, cmd(0), HOMED_VIEW, b"", True)
        pid = kw.parse_request(out.tx[:-1]).cmd_id if out.tx else None
    out = c.step(tick + 5, cmd(0), HOMED_VIEW, kw.format_reply(kw.Reply(kw.STAT, pid, state=kw.IDLE)), True)
    assert not out.fault and c.state == IDLE


def test_gmf1_programs_do_not_import_the_world():
    """docs/design.md §7: nothing outside droid/sim imports droid.sim (the programs reach the twin by URL)."""
    import pathlib

    import droid.subunits.gmf1 as pkg
    from tests.layering import droid_imports, within

    bad = []
    for path in pathlib.Path(pkg.__file__).parent.glob("*.py"):
        bad += [f"{path.name}: {n}" for n in droid_imports(path) if within(n, ("droid.sim",))]
    assert bad == []


def test_a_stop_drops_the_pending_command_and_the_move_in_flight_runs_out():
    """Issue 16: a task that gave up writes a stop (STOP_TICKS); what waited is never sent."""
    from droid.brain.db.layouts import STOP_TICKS

    c = opened_core()
    c.step(20, cmd(1), HOMED_VIEW, b"", True)  # in flight
    c.step(26, cmd(1), HOMED_VIEW, b"ACK 1 2.000\r\n", True)
    c.step(30, cmd(2), HOMED_VIEW, b"", True)  # waits as pending (a move is in flight)
    assert c.pending is not None and c.pending.cmd_id == 2
    out = c.step(31, cmd(3, ticks=STOP_TICKS), HOMED_VIEW, b"", True)
    assert c.pending is None and c.stops == 1
    assert out.fields["cmd_id"] == 3 and out.fields["cmd_result"] == CMD_OK
    out = c.step(200, cmd(3, ticks=STOP_TICKS), HOMED_VIEW, b"DONE 1\r\n", True)
    assert c.state == IDLE
    for t in range(201, 400, 20):  # command 2 is never sent
        assert c.step(t, cmd(3, ticks=STOP_TICKS), HOMED_VIEW, b"", True).tx == b""
