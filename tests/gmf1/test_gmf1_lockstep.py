"""The GMF1 in lockstep: Fanuc twin at 1 kHz, serial core per tick, encoder core at 120 Hz.

Virtual time only: these are verdicts on behaviour (counts, states, positions), never on speed.
"""
import numpy as np
import pytest

from droid.brain.db import arm_command
from droid.brain.db.layouts import CMD_FAILED, CMD_OK, CMD_REFUSED, FAULT_DEVICE, HOME_MODE
from droid.brain.runtime.remote import ArmPose
from droid.kinematics.transforms import T_to_pose, pose_to_T
from droid.sim.gmf1.lockstep import Gmf1Lockstep
from droid.subunits.gmf1 import karel_wire as kw

TARGET = [1060.51, -165.66, 2295.23, -170.0, 30.0, -160.0]  # global frame, reachable


@pytest.fixture
def g():
    return Gmf1Lockstep()


@pytest.fixture
def homed():
    g = Gmf1Lockstep()
    g.run_ticks(2)
    assert g.home()
    return g


def pose_of(status):
    return np.array([float(status["x"]), float(status["y"]), float(status["z"])])


def test_home_zeroes_the_counters_and_sets_homed(g):
    g.run_ticks(10)
    s = g.status()
    assert int(s["homed"]) == 0 and np.any(s["encoder_pos"] != 0)  # power-up counter values
    assert g.home()
    cmd_id = g.home_id
    s = g.status()
    assert int(s["homed"]) == 1 and int(s["cmd_id"]) == cmd_id and int(s["cmd_mode"]) == HOME_MODE
    assert np.all(np.abs(s["encoder_pos"]) <= 1)
    np.testing.assert_allclose(g.controller.q_deg, 0, atol=1e-9)
    np.testing.assert_allclose(pose_of(s), g.true_pose_global()[:3, 3], atol=1e-6)
    assert g.encoder_core.homings == 1 and not int(s["fault"]) & FAULT_DEVICE


def test_cart_move_at_the_controllers_pace_while_status_refreshes_at_120_hz(homed):
    g = homed
    seq = []
    g.sched.every(1000, lambda t: seq.append((t, g.ctrl_status.seq)), "watch", order=99)
    moves_before = g.controller.accepted
    refreshes_before = g.encoder.refreshes
    t0 = g.t_s
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(2.0))
    busy_seen = []
    assert g.run_until(lambda: busy_seen.append(int(g.status()["busy"])) or g.done(cmd_id), 20)
    elapsed = g.t_s - t0
    s = g.status()
    assert int(s["cmd_result"]) == CMD_OK and int(s["fault"]) == 0
    np.testing.assert_allclose(pose_of(s), TARGET[:3], atol=0.05)
    np.testing.assert_allclose(T_to_pose(g.true_pose_global()), TARGET, atol=1e-3)
    # one controller move for the command; it took at least the requested 2 s
    assert g.controller.accepted - moves_before == 1
    assert elapsed >= 2.0
    # the Status pose was refreshed at 120 Hz throughout, whatever the controller's 6 Hz did
    refreshes = g.encoder.refreshes - refreshes_before
    assert abs(refreshes - 120 * elapsed) <= 2
    # busy counted down in ticks, at least 1 while moving, 0 at the end
    assert max(busy_seen) >= 100 and busy_seen[-1] == 0
    assert all(b >= 1 for b in busy_seen[:-1])


def test_intermediate_commands_are_dropped_and_the_newest_wins(homed):
    g = homed
    base = np.array(TARGET)
    accepted_before = g.controller.accepted
    t_start = g.t_s
    ids = []
    for k in range(120):  # a new command every tick for 2 s (60 Hz), as a streaming task would
        p = base + np.array([0, 0.5 * k, 0, 0, 0, 0])
        ids.append(g.command_cart(pose_to_T(*p), g.ticks_for(0.1)))
        g.run_ticks(1)
    last = ids[-1]
    assert g.run_until(lambda: g.done(last), 20)
    np.testing.assert_allclose(pose_of(g.status())[1], base[1] + 0.5 * 119, atol=0.05)
    accepted = g.controller.accepted - accepted_before
    core = g.serial_core
    # the controller saw only a few of them, never more than its 6 Hz allows
    assert accepted <= 6 * (g.t_s - t_start) + 1 and accepted < 30
    assert core.dropped + accepted == 120
    assert core.dropped >= 90
    assert g.controller.busy_rejects == 0  # the program never hit the interpreter's cycle


def test_cart_command_before_homing_is_refused_and_nothing_moves(g):
    g.run_ticks(10)
    q0 = g.controller.q_deg.copy()
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(1.0))
    g.run_ticks(30)
    s = g.status()
    assert int(s["cmd_id"]) == cmd_id and int(s["cmd_result"]) == CMD_REFUSED and int(s["busy"]) == 0
    np.testing.assert_array_equal(g.controller.q_deg, q0)
    assert g.controller.accepted == 0


def test_unreachable_and_jog_commands_are_refused(homed):
    g = homed
    accepted = g.controller.accepted
    cmd_id = g.command_cart(pose_to_T(*[9000, 0, 0, 0, 0, 0]), g.ticks_for(1.0))
    g.run_ticks(5)
    assert int(g.status()["cmd_id"]) == cmd_id and int(g.status()["cmd_result"]) == CMD_REFUSED
    cmd_id = arm_command.jog(g.brain_command, np.full(6, 10, np.int32), 1)
    g.run_ticks(5)
    assert int(g.status()["cmd_id"]) == cmd_id and int(g.status()["cmd_result"]) == CMD_REFUSED
    assert g.controller.accepted == accepted


def test_joint_command_goes_as_jmove(homed):
    g = homed
    counts = g.model.gearing.joints_to_counts_int([5, 10, -5, 20, 30, -10]).astype(np.int32)
    cmd_id = g.command_joint(counts, g.ticks_for(1.0))
    assert g.run_until(lambda: g.done(cmd_id), 10)
    s = g.status()
    assert int(s["cmd_result"]) == CMD_OK
    assert np.all(np.abs(s["encoder_pos"] - counts) <= 1)
    np.testing.assert_array_equal(s["encoder_cmd"], counts)


def test_status_pose_agrees_with_the_remotes_forward_kinematics(homed):
    g = homed
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(1.0))
    g.run_ticks(40)  # mid-move
    s = g.status()
    T = ArmPose(g.sub)(s["encoder_pos"])
    np.testing.assert_allclose([T[0, 3], T[1, 3], T[2, 3]], pose_of(s), atol=1e-9)
    np.testing.assert_allclose(T[:3, :3], s["R"], atol=1e-12)
    assert g.run_until(lambda: g.done(cmd_id), 10)


def test_garbled_reply_line_gives_a_clear_fault_that_clears(homed):
    g = homed
    g.pair.device.write(b"D#NE 4x\xff\r\n")
    g.run_ticks(1)
    assert int(g.status()["fault"]) & FAULT_DEVICE
    assert g.serial_core.garbled == 1
    # the program checks the link (STAT) and the fault clears at the answer
    assert g.run_until(lambda: not int(g.status()["fault"]) & FAULT_DEVICE, 2.0)
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(0.5))
    assert g.run_until(lambda: g.done(cmd_id), 10)
    assert int(g.status()["cmd_result"]) == CMD_OK


def test_garbled_done_is_recovered_by_a_probe(homed):
    """The DONE of a move is mangled on the line: the move times out, is reported failed, and the
    probe finds the controller idle again; the next command works."""
    g = homed
    dev = g.pair.device
    real_write = dev.write

    def mangle(data):  # the controller's bytes leave one or two per world step: mangle the 'O' of DONE
        real_write(data.replace(b"O", b"#"))

    dev.write = mangle
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(0.5))
    assert g.run_until(lambda: int(g.status()["cmd_id"]) == cmd_id and int(g.status()["cmd_result"]) != CMD_OK, 15)
    s = g.status()
    assert int(s["cmd_result"]) == CMD_FAILED and int(s["busy"]) == 0 and int(s["fault"]) & FAULT_DEVICE
    dev.write = real_write
    assert g.run_until(lambda: not int(g.status()["fault"]) & FAULT_DEVICE, 5)
    cmd2 = g.command_cart(pose_to_T(*np.array(TARGET) + [0, 20, 0, 0, 0, 0]), g.ticks_for(0.5))
    assert g.run_until(lambda: g.done(cmd2), 10)
    assert int(g.status()["cmd_result"]) == CMD_OK


def test_stalled_controller_fails_the_move_and_stays_safe(homed):
    g = homed
    g.device.halted = True
    q = g.controller.q_deg.copy()
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(1.0))
    g.run_ticks(20)
    assert int(g.status()["busy"]) >= 1  # the command is out; no answer yet
    assert g.run_until(lambda: int(g.status()["cmd_result"]) == CMD_FAILED, 10)
    s = g.status()
    assert int(s["fault"]) & FAULT_DEVICE and int(s["busy"]) == 0 and int(s["cmd_id"]) == cmd_id
    np.testing.assert_array_equal(g.controller.q_deg, q)
    # more commands while stalled are held, not sent blind
    cmd2 = g.command_cart(pose_to_T(*np.array(TARGET) + [0, 10, 0, 0, 0, 0]), g.ticks_for(0.5))
    g.run_ticks(240)
    assert int(g.status()["cmd_id"]) == cmd_id
    assert g.serial_core.timeouts >= 2
    # the controller comes back: the fault clears and the held command runs
    g.device.halted = False
    assert g.run_until(lambda: g.done(cmd2), 15)
    assert int(g.status()["cmd_result"]) == CMD_OK and not int(g.status()["fault"]) & FAULT_DEVICE


def test_vanished_port_is_a_fault_and_is_reopened(homed):
    g = homed
    opens = g.link.opens
    g.pair.vanish()
    g.run_ticks(3)
    assert not g.link.is_open and int(g.status()["fault"]) & FAULT_DEVICE
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(0.5))
    g.run_ticks(120)  # back-off reopen attempts fail meanwhile, never an exception
    assert int(g.status()["fault"]) & FAULT_DEVICE and int(g.status()["busy"]) == 1
    g.pair.restore()
    assert g.run_until(lambda: g.done(cmd_id), 15)
    assert g.link.opens > opens and not int(g.status()["fault"]) & FAULT_DEVICE
    np.testing.assert_allclose(pose_of(g.status()), TARGET[:3], atol=0.05)


def test_port_vanishing_mid_move(homed):
    g = homed
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(2.0))
    g.run_ticks(30)
    g.pair.vanish()
    g.run_ticks(30)
    g.pair.restore()
    # after the reopen the probe finds the move running (or done) and the program follows it
    assert g.run_until(lambda: g.done(cmd_id), 15)
    assert int(g.status()["cmd_result"]) == CMD_OK
    np.testing.assert_allclose(pose_of(g.status()), TARGET[:3], atol=0.05)


def test_encoder_cards_stop_answering_resets(homed):
    """A reset the cards never execute: device fault, homed stays 0, retried later."""
    g = homed
    # freeze the card side: commands are never executed
    g.device.twin.update = lambda motor=None: None
    cmd_id = g.command_home()
    assert g.run_until(lambda: g.done(cmd_id), 10)
    assert g.run_until(lambda: int(g.status()["fault"]) & FAULT_DEVICE, 2)
    assert int(g.status()["homed"]) == 0 and g.encoder_core.resets >= 1


def test_same_seed_same_run():
    def trial():
        g = Gmf1Lockstep(seed=5)
        g.run_ticks(2)
        assert g.home()
        cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(1.0))
        g.run_until(lambda: g.done(cmd_id), 10)
        return g.t_s, g.status().tobytes(), g.controller.q_deg.tobytes()

    a, b = trial(), trial()
    assert a[0] == b[0] and a[2] == b[2]
    assert a[1] == b[1]


def test_requests_on_the_line_follow_the_grammar(homed):
    """Everything the program wrote to the port parses as a request."""
    g = homed
    seen = bytearray()
    port_write = g.link.write

    def spy(data):
        seen.extend(data)
        return port_write(data)

    g.link.write = spy
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(0.5))
    assert g.run_until(lambda: g.done(cmd_id), 10)
    lines = kw.LineSplitter().feed(bytes(seen))
    reqs = [kw.parse_request(ln) for ln in lines]
    assert [r.verb for r in reqs] == [kw.MOVE] and reqs[0].cmd_id == cmd_id
    assert reqs[0].duration_s == pytest.approx(0.5)


def test_the_protective_stop_halts_a_move_in_flight_and_refuses_the_next(homed):
    """Issue 41: FAULT_COLLISION in the Status (the collision guard) -> HALT: the Fanuc ends its move
    along its path, short of the target, CMD_FAILED; a NORMAL command while it is set is refused."""
    from droid.brain.db.layouts import FAULT_COLLISION
    from droid.guard.gate import set_fault_bit

    g = homed
    start = g.controller.q_deg.copy()
    cmd_id = g.command_cart(pose_to_T(*TARGET), g.ticks_for(3.0))
    assert g.run_until(lambda: g.controller.moving_at(g.t_s) and g.t_s > 1.0 + g.controller.motion.t0, 10)
    mid = g.controller.q_deg.copy()
    set_fault_bit(g.ctrl_status, FAULT_COLLISION, True)
    assert g.run_until(lambda: not g.controller.moving_at(g.t_s), 3.0)
    g.run_ticks(30)
    s = g.status()
    assert int(s["cmd_id"]) == cmd_id and int(s["cmd_result"]) == CMD_FAILED and int(s["busy"]) == 0
    assert g.serial_core.halts == 1 and g.controller.halts == 1
    end = g.controller.q_deg
    assert np.max(np.abs(end - mid)) > 0 and np.max(np.abs(end - start)) > 0  # on from where it was halted
    assert not np.allclose(T_to_pose(g.true_pose_global())[:3], TARGET[:3], atol=5.0)  # short of the target
    second = g.command_cart(pose_to_T(*TARGET), g.ticks_for(3.0))
    g.run_ticks(20)
    s = g.status()
    assert int(s["cmd_id"]) == second and int(s["cmd_result"]) == CMD_REFUSED
    assert not g.controller.moving_at(g.t_s)
    set_fault_bit(g.ctrl_status, FAULT_COLLISION, False)  # released: moves again
    third = g.command_cart(pose_to_T(*TARGET), g.ticks_for(2.0))
    assert g.run_until(lambda: g.done(third), 20)
    assert int(g.status()["cmd_result"]) == CMD_OK
