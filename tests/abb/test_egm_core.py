"""droid-egm's core (issue 26): datagram checks, sequence bookkeeping, reconnects, the stale rule,
the target it sends.  Pure: no sockets, virtual time [ns]."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from abb_robot_client._egm_protobuf import egm_pb2
from droid.brain.db.layouts import (CMD_OK, FAULT_BRAKING, FAULT_DEVICE, FAULT_SERVO, HOME_MODE, HOMED, JOG_MODE,
                                 NORMAL_MODE, OFF)
from droid.kinematics import load_robot
from droid.subunits.abb.egm_core import MAX_DATAGRAM_BYTES, SEQ_WINDOW, EgmCore, SeqTracker
from tests.abb.egm_helpers import CONTROLLER, MS, command, counts, decode_sensor, robot_bytes

MODEL = load_robot("abb_irb2400")
STALE_TICKS = 12
PERIOD_NS = int(round(1e9 / 60.0))


def core() -> EgmCore:
    return EgmCore(MODEL, STALE_TICKS, 60.0)


def feed(c: EgmCore, seqnos, t0_ns=0, source=CONTROLLER, **kw):
    """Datagrams with these sequence numbers, 4 ms apart; the replies."""
    return [c.datagram(robot_bytes(s, **kw), source, t0_ns + i * 4 * MS) for i, s in enumerate(seqnos)]


# -- sequence numbers -------------------------------------------------------------------------

def test_in_order_stream_is_accepted_and_answered():
    c = core()
    replies = feed(c, range(1, 51))
    assert all(r is not None and r[1] == CONTROLLER for r in replies)
    k = c.counters
    assert (k.accepted, k.lost, k.late, k.duplicated, k.reordered, k.replies) == (50, 0, 0, 0, 0, 50)
    assert c.sample.seqno == 50


def test_lost_packets_are_the_gaps():
    c = core()
    feed(c, [1, 2, 5, 6, 10])
    assert c.counters.lost == 2 + 3
    assert c.counters.accepted == 5


def test_duplicates_are_counted_and_dropped():
    c = core()
    replies = feed(c, [1, 2, 2, 3, 3, 3, 1])
    assert replies[2] is None and replies[4] is None and replies[5] is None and replies[6] is None
    assert c.counters.duplicated == 4
    assert c.sample.seqno == 3


def test_reordered_packet_is_counted_not_lost_and_the_newest_wins():
    c = core()
    feed(c, [1, 2, 4], joints=(1, 1, 1, 1, 31, 1))
    assert c.counters.lost == 1
    r = c.datagram(robot_bytes(3, joints=(9, 9, 9, 9, 9, 9)), CONTROLLER, 20 * MS)
    assert r is None  # an older sample never overrides the newest
    assert c.counters.reordered == 1 and c.counters.lost == 0
    assert c.sample.seqno == 4 and c.sample.feedback_deg[0] == 1.0
    assert c.datagram(robot_bytes(3), CONTROLLER, 24 * MS) is None
    assert c.counters.duplicated == 1  # the same one twice


def test_late_packet_beyond_the_window():
    c = core()
    feed(c, range(100, 100 + SEQ_WINDOW + 5))
    r = c.datagram(robot_bytes(100, tm=400), CONTROLLER, 150 * MS)
    assert r is None and c.counters.late == 1


def test_sequence_numbers_wrap_at_2_32():
    c = core()
    feed(c, [2**32 - 2, 2**32 - 1, 0, 1, 3])
    assert c.counters.accepted == 5 and c.counters.lost == 1
    tr = SeqTracker()
    tr.classify(2**32 - 1)
    assert tr.classify(0) == "new" and tr.gap == 0


def test_reconnect_from_another_port_takes_any_number_and_replies_there():
    c = core()
    feed(c, range(1000, 1010))
    other = ("127.0.0.1", 40999)
    r = c.datagram(robot_bytes(1), other, 50 * MS)
    assert r is not None and r[1] == other
    assert c.counters.reconnects == 1 and c.source == other
    r = c.datagram(robot_bytes(2), other, 54 * MS)
    assert r is not None and r[1] == other
    # the old port's stragglers are not the controller any more: a reconnect back, never a mix
    assert c.counters.lost == 0 and c.counters.accepted == 12


def test_egm_restart_on_the_same_port_is_a_reconnect():
    """Numbers start again while the controller's clock (EgmHeader.tm) runs on."""
    c = core()
    feed(c, range(5000, 5100))  # tm = 4 * seqno
    r = c.datagram(robot_bytes(1, tm=4 * 5100 + 500), CONTROLLER, 500 * MS)
    assert r is not None and c.counters.reconnects == 1 and c.counters.late == 0
    assert c.datagram(robot_bytes(2, tm=4 * 5100 + 504), CONTROLLER, 504 * MS) is not None


# -- what is dropped -----------------------------------------------------------------------------

def test_malformed_truncated_oversized_foreign_are_counted_and_never_answered():
    c = core()
    good = robot_bytes(1)
    before = c.target(0)[0]
    assert before is None
    cases = {
        "malformed": [b"\xff\xff\xff\xff", b"\x0a\x05abc", good[:7], b"", b"\x08"],
        "oversized": [good + b"\x00" * (MAX_DATAGRAM_BYTES + 1 - len(good)), b"\x00" * 70000],
    }
    sensor = egm_pb2.EgmSensor()
    sensor.header.seqno, sensor.header.mtype = 1, egm_pb2.EgmHeader.MSGTYPE_CORRECTION
    sensor.planned.joints.joints.extend([0.0] * 6)
    cases["foreign"] = [sensor.SerializeToString(), robot_bytes(2, mtype=egm_pb2.EgmHeader.MSGTYPE_COMMAND)]
    nan_joints = robot_bytes(3, joints=(0, 0, float("nan"), 0, 0, 0))
    five = robot_bytes(4, joints=(0, 0, 0, 0, 0))
    huge = robot_bytes(5, joints=(0, 0, 1e9, 0, 0, 0))
    cases["malformed"] += [nan_joints, five, huge]
    no_seq = egm_pb2.EgmRobot()
    no_seq.header.mtype = egm_pb2.EgmHeader.MSGTYPE_DATA
    no_seq.feedBack.joints.joints.extend([0.0] * 6)
    cases["malformed"].append(no_seq.SerializeToString())
    for data_list in cases.values():
        for data in data_list:
            assert c.datagram(data, CONTROLLER, 0) is None
    assert c.counters.malformed == len(cases["malformed"])
    assert c.counters.oversized == 2
    assert c.counters.foreign == 2
    assert c.counters.accepted == 0 and c.counters.replies == 0 and c.sample is None
    out = c.cycle(command(), 10 * MS)
    assert out.fault_bits & FAULT_DEVICE and out.status["homed"] == 0
    assert "encoder_cmd" not in out.status  # nothing to command: no position known


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=2000))
def test_fuzz_random_datagrams_never_crash_or_move(data):
    c = core()
    feed(c, [1], joints=(5, 5, 5, 5, 35, 5))
    q_before = c.target(4 * MS)[0].copy()
    r = c.datagram(data, CONTROLLER, 8 * MS)
    if r is None:
        assert np.array_equal(c.target(8 * MS)[0], q_before)
        assert c.sample.seqno == 1
    else:  # random bytes that happen to be a well-formed robot DATA message
        assert c.counters.accepted == 2
    out = c.cycle(command(OFF), 8 * MS)
    assert np.all(np.abs(c.target(8 * MS)[0]) <= 3600)
    assert out.status["cmd_mode"] == OFF


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.lists(st.integers(-40, 40), min_size=1, max_size=60))
def test_fuzz_sequences_keep_the_counts_consistent(start, steps):
    """Whatever order numbers come in: every datagram is counted once, and the newest wins."""
    c = core()
    seqnos = [start]
    for s in steps:
        seqnos.append((seqnos[-1] + s) & 0xFFFFFFFF)
    feed(c, seqnos)
    k = c.counters
    assert k.accepted + k.late + k.duplicated + k.reordered == len(seqnos)  # a reconnect is accepted
    assert k.lost >= 0


# -- the heartbeat cycle ---------------------------------------------------------------------------

def test_homed_at_once_and_home_acknowledged():
    c = core()
    feed(c, [1, 2, 3], joints=(10, 20, 30, 40, 50, 60))
    out = c.cycle(command(HOME_MODE, cmd_id=7), 12 * MS)
    assert out.status["homed"] == HOMED
    assert out.status["cmd_id"] == 7 and out.status["cmd_result"] == CMD_OK and out.status["busy"] == 0
    assert out.fault_bits == 0
    assert np.array_equal(out.status["encoder_pos"], counts(MODEL, [10, 20, 30, 40, 50, 60]))
    assert out.egm["seqno"] == 3 and out.egm["motor_state"] == egm_pb2.EgmMotorState.MOTORS_ON
    assert out.egm["sample_age_us"] == 4000  # the newest sample came at 8 ms, written at 12 ms


def test_home_before_feedback_waits_busy_then_acks():
    c = core()
    c.cycle(command(OFF, cmd_id=1), 0)
    out = c.cycle(command(HOME_MODE, cmd_id=2), PERIOD_NS)
    assert out.status["busy"] == 1 and out.status["homed"] == 0
    feed(c, [1], t0_ns=2 * PERIOD_NS)
    out = c.cycle(command(HOME_MODE, cmd_id=2), 2 * PERIOD_NS + MS)
    assert out.status["homed"] == HOMED and out.status["cmd_id"] == 2 and out.status["busy"] == 0


def test_stale_feedback_sets_the_link_fault_and_unhomes():
    c = core()
    feed(c, [1, 2, 3])
    t_last = 8 * MS
    out = c.cycle(command(), t_last + STALE_TICKS * PERIOD_NS - 1)
    assert not out.fault_bits & FAULT_DEVICE and out.status["homed"] == HOMED
    out = c.cycle(command(), t_last + STALE_TICKS * PERIOD_NS)
    assert out.fault_bits & FAULT_DEVICE and out.status["homed"] == 0 and out.why == "EGM feedback stale"
    # a host stall: the silence counts only while this program was awake
    out = c.cycle(command(), t_last + STALE_TICKS * PERIOD_NS, late_ns=PERIOD_NS)
    assert not out.fault_bits & FAULT_DEVICE
    # the first sample after the stale period is taken whatever its number (a resync)
    assert c.datagram(robot_bytes(1), CONTROLLER, 10**9) is not None
    assert c.cycle(command(OFF), 10**9 + MS).fault_bits == 0


@pytest.mark.parametrize("what", ["motors", "rapid", "mci"])
def test_controller_not_guiding_is_a_servo_fault_and_holds_on_the_feedback(what):
    c = core()
    feed(c, [1], joints=(1, 2, 3, 4, 35, 6))
    kw = {"motors": dict(motors=egm_pb2.EgmMotorState.MOTORS_OFF),
          "rapid": dict(rapid=egm_pb2.EgmRapidCtrlExecState.RAPID_STOPPED),
          "mci": dict(mci=egm_pb2.EgmMCIState.MCI_STOPPED)}[what]
    feed(c, [2], t0_ns=4 * MS, joints=(1.5, 2, 3, 4, 35, 6), **kw)
    out = c.cycle(command(cmd_id=3, encoder_cmd_int=counts(MODEL, [20, 20, 20, 20, 20, 20]),
                          brain_tick=1, planner_tick=1), 5 * MS)
    assert out.fault_bits & FAULT_SERVO and out.status["homed"] == HOMED
    assert np.allclose(c.target(5 * MS)[0], [1.5, 2, 3, 4, 35, 6])


def test_follows_the_planner_interpolated_over_one_period():
    c = core()
    q0 = np.array([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])
    feed(c, [1], joints=q0)
    c.cycle(command(brain_tick=1, planner_tick=1, encoder_cmd_int=counts(MODEL, q0)), MS)
    q1 = q0 + [1.0, -0.5, 0.5, 2.0, -1.0, 1.0]  # within one period at the speed limits
    t = MS + PERIOD_NS
    c.cycle(command(brain_tick=2, planner_tick=2, encoder_cmd_int=counts(MODEL, q1)), t)
    half = c.target(t + PERIOD_NS // 2)[0]
    assert np.allclose(half, (q0 + q1) / 2, atol=2e-3)
    r = c.datagram(robot_bytes(2, joints=q0), CONTROLLER, t + PERIOD_NS // 2)
    msg = decode_sensor(r[0])
    assert msg.header.mtype == egm_pb2.EgmHeader.MSGTYPE_CORRECTION
    assert np.allclose(list(msg.planned.joints.joints), half)
    assert np.allclose(list(msg.speedRef.joints.joints), (q1 - q0) * 60.0, rtol=1e-3, atol=0.2)
    assert np.allclose(c.target(t + 2 * PERIOD_NS)[0], q1, atol=2e-3)


def test_a_way_point_too_far_is_refused_with_braking():
    c = core()
    feed(c, [1])
    c.cycle(command(brain_tick=1, planner_tick=1, encoder_cmd_int=counts(MODEL, [0, 0, 0, 0, 30, 0])), MS)
    out = c.cycle(command(brain_tick=2, planner_tick=2,
                          encoder_cmd_int=counts(MODEL, [20, 0, 0, 0, 30, 0])), MS + PERIOD_NS)
    assert out.fault_bits & FAULT_BRAKING
    assert np.allclose(c.target(MS + 2 * PERIOD_NS)[0], [0, 0, 0, 0, 30, 0])


@pytest.mark.parametrize("cause", ["link", "planner"])
def test_brain_link_lost_or_planner_silent_holds(cause):
    c = core()
    feed(c, [1])
    q1 = np.array([1.0, 0, 0, 0, 30, 0])
    c.cycle(command(brain_tick=1, planner_tick=1, encoder_cmd_int=counts(MODEL, [0, 0, 0, 0, 30, 0])), MS)
    c.cycle(command(brain_tick=2, planner_tick=2, encoder_cmd_int=counts(MODEL, q1)), MS + PERIOD_NS)
    kw = dict(link_alive=0, brain_tick=3, planner_tick=3) if cause == "link" else \
        dict(brain_tick=2 + STALE_TICKS + 1, planner_tick=2)
    t = MS + 2 * PERIOD_NS
    out = c.cycle(command(encoder_cmd_int=counts(MODEL, q1 * 5), **kw), t)
    assert out.why in ("Brain link lost", "planner silent")
    assert np.allclose(c.target(t + 10 * PERIOD_NS)[0], q1, atol=2e-3)


def test_jog_moves_the_target_once_by_its_counts():
    c = core()
    feed(c, [1])
    c.cycle(command(JOG_MODE, cmd_id=1), MS)
    delta = counts(MODEL, [1, 0, 0, 0, 0, -2])
    out = c.cycle(command(JOG_MODE, cmd_id=2, encoder_cmd_ext=delta), MS + PERIOD_NS)
    assert out.status["cmd_id"] == 2 and out.status["busy"] == 0
    assert np.allclose(c.target(MS + PERIOD_NS)[0], [1, 0, 0, 0, 30, -2], atol=1e-3)
    c.cycle(command(JOG_MODE, cmd_id=2, encoder_cmd_ext=delta), MS + 2 * PERIOD_NS)
    assert np.allclose(c.target(MS + 2 * PERIOD_NS)[0], [1, 0, 0, 0, 30, -2], atol=1e-3)  # once


def test_step_takes_datagrams_then_cycles():
    c = core()
    dgs = [(robot_bytes(i), CONTROLLER, i * 4 * MS) for i in (1, 2, 2, 3)]
    out = c.step(dgs, command(NORMAL_MODE), 13 * MS)
    assert len(out.replies) == 3 and c.counters.duplicated == 1
    assert out.status["homed"] == HOMED


def test_after_a_fault_hold_an_old_way_point_is_never_resumed():
    """Feedback stale mid-move, then back: the way-point still in the Command record (the
    planner stops writing while the arm is not homed) is not driven to; the planner's
    re-anchored one (at the arm) is followed again."""
    c = core()
    q0 = np.array([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])
    feed(c, [1], joints=q0)
    c.cycle(command(brain_tick=1, planner_tick=1, encoder_cmd_int=counts(MODEL, q0)), MS)
    q1 = q0 + [1.0, 0, 0, 0, 0, 0]
    c.cycle(command(brain_tick=2, planner_tick=2, encoder_cmd_int=counts(MODEL, q1)), MS + PERIOD_NS)
    assert c.reanchor is False
    out = c.cycle(command(brain_tick=30, planner_tick=30, encoder_cmd_int=counts(MODEL, q1)), 10**9)
    assert out.fault_bits & FAULT_DEVICE
    here = q0 + [0.4, 0, 0, 0, 0, 0]  # where the arm stopped
    c.datagram(robot_bytes(1, joints=here), CONTROLLER, 2 * 10**9)
    out = c.cycle(command(brain_tick=31, planner_tick=31, encoder_cmd_int=counts(MODEL, q1)), 2 * 10**9 + MS)
    assert out.why == "waiting for the planner to re-anchor" and out.fault_bits == 0
    assert np.allclose(c.target(2 * 10**9 + 3 * PERIOD_NS)[0], here)
    c.cycle(command(brain_tick=32, planner_tick=32, encoder_cmd_int=counts(MODEL, here)), 2 * 10**9 + PERIOD_NS)
    assert c.reanchor is False
    q2 = here + [0.5, 0, 0, 0, 0, 0]
    c.cycle(command(brain_tick=33, planner_tick=33, encoder_cmd_int=counts(MODEL, q2)), 2 * 10**9 + 2 * PERIOD_NS)
    assert np.allclose(c.target(2 * 10**9 + 4 * PERIOD_NS)[0], q2, atol=2e-3)


def test_a_move_commanded_as_normal_returns_after_home_is_followed_from_its_first_way_point():
    """In HOME (JOG, OFF) the planner follows the arm: its fresh way-point at the feedback is a
    re-anchored planner, so a move commanded in the tick NORMAL returns (a task right after
    droid-home) is followed -- before, it was held forever while the planner reported it done."""
    c = core()
    q0 = np.array([0.0, 10.0, 10.0, 0.0, 60.0, 0.0])
    feed(c, [1], joints=q0)
    c.cycle(command(HOME_MODE, cmd_id=1, brain_tick=1, planner_tick=1, encoder_cmd_int=counts(MODEL, q0)), MS)
    assert c.reanchor is False
    q1 = q0 + [0.5, 0.0, 0.0, 0.0, 0.0, -0.5]  # the move's first way-point, one tick along
    out = c.cycle(command(NORMAL_MODE, cmd_id=2, brain_tick=2, planner_tick=2, encoder_cmd_int=counts(MODEL, q1)),
                  MS + PERIOD_NS)
    assert out.why == "" and out.fault_bits == 0
    assert np.allclose(c.target(MS + 2 * PERIOD_NS)[0], q1, atol=2e-3)


def test_in_home_a_planner_way_point_away_from_the_arm_does_not_end_the_re_anchoring():
    c = core()
    q0 = np.array([0.0, 10.0, 10.0, 0.0, 60.0, 0.0])
    feed(c, [1], joints=q0)
    old = counts(MODEL, q0 + [3.0, 0, 0, 0, 0, 0])  # a way-point left from before, or a silent planner's
    c.cycle(command(HOME_MODE, cmd_id=1, brain_tick=1, planner_tick=1, encoder_cmd_int=old), MS)
    assert c.reanchor is True
    c.cycle(command(HOME_MODE, cmd_id=1, brain_tick=2 + STALE_TICKS, planner_tick=1,
                    encoder_cmd_int=counts(MODEL, q0)), MS + PERIOD_NS)
    assert c.reanchor is True  # at the arm, but the planner is silent
