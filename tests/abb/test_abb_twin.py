"""The ABB EGM controller twin (issue 26) driven by an independent EGM client: abb-robot-client's
``EGM`` (PyPI, Apache-2.0), over real UDP sockets on 127.0.0.1.

The world is stepped in virtual time: the test calls the device's ``advance(dt_s)`` and drains
the client's socket after every step; loopback UDP delivers a datagram before ``sendto``
returns, and a bounded drain at the end collects any straggler, so no real-time wait decides a
verdict (the counts are of world time)."""
from __future__ import annotations

import select
import socket
import time

import numpy as np
import pytest
from abb_robot_client.egm import EGM

from droid.kinematics import load_robot
from droid.sim.abb.controller import AbbEgmDevice, EgmController, EgmTwinParams, open_socket
from droid.kinematics.transforms import pose_to_T

MODEL = load_robot("abb_irb2400")
DT_S = 0.001  # the world's step (droid-sim's 1 kHz)
START = [0.0, 10.0, 10.0, 0.0, 60.0, 0.0]


def client_on_loopback() -> EGM:
    """abb-robot-client's EGM client, unchanged, on a socket bound to 127.0.0.1 (its constructor
    binds every interface; the tests stay on loopback)."""
    egm = EGM.__new__(EGM)
    egm.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    egm.socket.bind(("127.0.0.1", 0))
    egm.send_sequence_number = 0
    egm.egm_addr = None
    egm.count = 0
    return egm


@pytest.fixture
def rig():
    client = client_on_loopback()
    ctrl = EgmController(MODEL, EgmTwinParams(test_signals=True), START)
    dev = AbbEgmDevice("abb", ctrl, open_socket(0, "test"), client.socket.getsockname(), MODEL.with_base(pose_to_T(0, 0, 0, 0, 0, 0)))
    yield client, dev
    dev.close()
    client.close()


def drain(client: EGM, timeout_s: float = 0.0):
    states = []
    while True:
        ok, st = client.receive_from_robot(timeout_s)
        if not ok:
            return states
        states.append(st)


def final_drain(client: EGM, want: int, have: int):
    """Stragglers: read until ``want`` arrived or the socket stays empty for 0.5 s (bounded)."""
    states = []
    end = time.monotonic() + 5.0
    while have + len(states) < want and time.monotonic() < end:
        got = drain(client, 0.5)
        if not got:
            break
        states += got
    return states


def test_feedback_at_250_hz_of_world_time(rig):
    client, dev = rig
    steps = 1000  # 1 s of world time
    states = []
    for _ in range(steps):
        dev.advance(DT_S)
        states += drain(client)
    states += final_drain(client, 251, len(states))
    # sends at t = 0, 4, ..., 1000 ms
    assert len(states) == 251
    seqnos = [s.robot_message.header.seqno for s in states]
    assert seqnos == list(range(1, 252))
    tms = [s.robot_message.header.tm for s in states]
    assert tms == [4 * k for k in range(251)]  # ms of world time
    s = states[-1]
    assert s.motors_on and s.rapid_running
    assert np.allclose(s.joint_angles, START, atol=0.01)
    assert np.allclose(s.joint_angles_planned, START, atol=1e-6)
    m = states[100].robot_message  # (EGMRunJoint times out at 1 s without a sensor message)
    assert m.mciState.state == m.mciState.MCI_RUNNING and m.mciConvergenceMet
    m = s.robot_message
    assert len(m.testSignals.signals) == 6
    assert dev.send_errors == 0


def test_joint_targets_move_the_twin_to_within_0_01_deg(rig):
    client, dev = rig
    target = np.array([15.0, 20.0, 0.0, -30.0, 45.0, 90.0])
    state = None
    for _ in range(3000):  # 3 s of world time; the largest move, 90 deg at 450 deg/s, takes 0.2 s
        dev.advance(DT_S)
        for state in drain(client):
            assert client.send_to_robot(target)
    assert state is not None
    assert np.max(np.abs(dev.controller.q_motor_deg - target)) < 0.01
    assert np.max(np.abs(np.asarray(state.joint_angles) - target)) < 0.01
    assert dev.controller.received > 700 and dev.controller.bad == 0
    assert dev.controller.converged


def test_joint_speed_limits_hold_on_the_reference(rig):
    client, dev = rig
    target = np.array([90.0, 10.0, 10.0, 0.0, 60.0, 0.0])  # 90 deg on joint 1, vmax 150 deg/s
    worst = 0.0
    prev = dev.controller.ref_deg.copy()
    for _ in range(300):
        dev.advance(DT_S)
        for _s in drain(client):
            client.send_to_robot(target)
        ref = dev.controller.ref_deg
        worst = max(worst, float(np.max(np.abs(ref - prev) / DT_S / MODEL.vmax_deg_s)))
        prev = ref.copy()
    assert 0.99 < worst <= 1.0 + 1e-9
    assert dev.controller.q_deg[0] < 50.0  # 0.3 s at <= 150 deg/s


def test_silent_sensor_stops_guidance_and_the_arm_holds():
    """EGM's communication timeout (50 ms here, to stop mid-move): guidance ends (MCI STOPPED),
    the arm stops short of the last target and holds; the RAPID loop restarts EGMRunJoint."""
    client = client_on_loopback()
    ctrl = EgmController(MODEL, EgmTwinParams(comm_timeout_s=0.05, restart_s=0.5), START)
    dev = AbbEgmDevice("abb", ctrl, open_socket(0, "test"), client.socket.getsockname(), MODEL)
    try:
        target = np.array([60.0, 10.0, 10.0, 0.0, 60.0, 0.0])
        for _ in range(100):  # 0.1 s of guidance toward the target (reference at 150 deg/s)
            dev.advance(DT_S)
            for _s in drain(client):
                client.send_to_robot(target)
        assert ctrl.guiding
        states = []
        for _ in range(300):  # then silence: timeout at 0.15 s, hold for the rest
            dev.advance(DT_S)
            states += drain(client)
        assert ctrl.timeouts == 1 and not ctrl.guiding
        assert 5.0 < ctrl.q_deg[0] < 40.0  # stopped between start and target
        q_hold = ctrl.q_deg.copy()
        for _ in range(150):
            dev.advance(DT_S)
            states += drain(client)
        assert np.max(np.abs(ctrl.q_deg - q_hold)) < 0.01  # and it holds there
        m = states[-1].robot_message
        assert m.mciState.state == m.mciState.MCI_STOPPED and m.rapidExecState.state == m.rapidExecState.RAPID_RUNNING
        later = []
        for _ in range(200):  # 0.5 s after the timeout the RAPID loop runs EGMRunJoint again,
            dev.advance(DT_S)  # which times out again 50 ms later: nobody answers
            later += drain(client)
        running = [x.robot_message.mciState.state == m.mciState.MCI_RUNNING for x in later]
        assert any(running) and not running[-1] and ctrl.timeouts == 2
    finally:
        dev.close()
        client.close()


def test_motors_off_and_rapid_stopped_are_reported(rig):
    client, dev = rig
    dev.controller.set_motors(False)
    for _ in range(4):  # one EGM period
        dev.advance(DT_S)
    s = drain(client)[-1]
    assert not s.motors_on and s.robot_message.mciState.state == s.robot_message.mciState.MCI_STOPPED
    client.send_to_robot(np.array([40.0, 10, 10, 0, 60, 0]))
    for _ in range(200):
        dev.advance(DT_S)
        drain(client)
    assert np.allclose(dev.controller.q_deg, START, atol=1e-9)  # the brakes hold: nothing moves
    dev.controller.set_motors(True)
    dev.controller.set_rapid(False)
    for _ in range(4):
        dev.advance(DT_S)
    s = drain(client)[-1]
    assert s.motors_on and not s.rapid_running


def test_garbage_to_the_twin_is_counted_and_ignored(rig):
    client, dev = rig
    dev.advance(DT_S)
    drain(client)
    for junk in (b"", b"\xff" * 40, b"\x0a\x02\x18\x01"):
        client.socket.sendto(junk, dev.address)
    for _ in range(20):
        dev.advance(DT_S)
        drain(client)
    assert dev.controller.bad == 3 and dev.controller.received == 0
    assert np.allclose(dev.controller.q_deg, START, atol=0.01)


def test_device_from_the_abb_weld_cell_binds_loopback_only(tmp_path):
    from droid.brain.cell.cellfile import load_cell
    from droid.cli import BadInput
    from droid.sim.abb.controller import make_abb_egm

    class World:
        seed = 1

    w = World()
    w.cell = load_cell("cells/abb_weld.toml")
    dev = make_abb_egm(w, "abb", {"subunit": "abb", "start_deg": START, "comm_timeout_s": 0.5})
    try:
        from droid.brain.cell.cellfile import loopback_address

        own = loopback_address(w.cell.name)  # the cell's own 127.x.y.z ({loopback} in the cell file)
        assert dev.address[0] == own and dev.sensor_addr == (own, 6510)
        assert dev.controller.p.comm_timeout_s == 0.5 and dev.controller.arm is not None
    finally:
        dev.close()
    for bad in ({"subunit": "abb", "comm_timeout_s": -1.0}, {"subunit": "abb", "colour": 1},
                {"subunit": "abb", "start_deg": [0, 0, 500, 0, 0, 0]}, {"subunit": "abb", "dynamics": 1}):
        with pytest.raises(BadInput):
            make_abb_egm(w, "abb", bad)
    assert select.select  # (imported for the drains above)


def _correction(joints) -> bytes:
    from abb_robot_client._egm_protobuf import egm_pb2  # the independent client's message definitions

    m = egm_pb2.EgmSensor()
    m.header.seqno, m.header.mtype = 1, egm_pb2.EgmHeader.MSGTYPE_CORRECTION
    m.planned.joints.joints.extend(float(v) for v in joints)
    return m.SerializeToString()


def test_a_reference_at_rest_on_its_target_is_left_bit_for_bit_as_the_ramp_leaves_it():
    """The twin skips the reference's ramp while the reference stands on its target at rest: over
    moves, holds of the same target (sent again every 4 ms, as the EGM program does) and a stop,
    every datagram, the reference, its rate and the joints are the same bits as a twin that ramps
    every step."""
    fast, full = (EgmController(MODEL, EgmTwinParams(test_signals=True), START) for _ in range(2))
    full.rest_shortcut = False
    for c in (fast, full):
        c.set_rapid(True)
        c.set_motors(True)
    rng = np.random.default_rng(3)
    target = np.array(START, float)
    t = 0.0
    for k in range(6000):  # 6 s of 1 ms steps
        if k % 1500 == 0:  # a new target every 1.5 s: ~1 s of motion, then a hold
            target = target + rng.uniform(-4.0, 4.0, 6)
        t = (k + 1) * DT_S
        if k % 4 == 0 and k < 4600:  # the sensor goes silent at 4.6 s: after 1 s a timeout ramps to rest
            for c in (fast, full):
                c.receive(_correction(target), t)
        a, b = fast.advance(t), full.advance(t)
        assert a == b, k
        for f in ("ref_deg", "ref_rate", "q_motor_deg"):
            assert np.asarray(getattr(fast, f)).tobytes() == np.asarray(getattr(full, f)).tobytes(), (k, f)
    assert fast.timeouts == full.timeouts == 1
