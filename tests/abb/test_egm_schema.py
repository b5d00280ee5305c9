"""EGM on the wire (issue 26): the schema droid-egm and the twin use is ABB's, droid-egm's datagrams
decode with the official schema's generated classes, and a captured exchange decodes.

The decoding side here is abb-robot-client's generated ``egm_pb2`` plus protobuf's own wire
reader (``UnknownFieldSet`` on an empty message: field numbers and wire types straight from the
bytes, no schema at all), so a wrong field number on our side would show."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from google.protobuf import empty_pb2
from google.protobuf.unknown_fields import UnknownFieldSet

from abb_robot_client._egm_protobuf import egm_pb2
from droid.kinematics import load_robot
from droid.subunits.abb import egm_schema
from droid.subunits.abb.egm_core import EgmCore
from tests.abb.egm_helpers import CONTROLLER, MS, command, counts, robot_bytes

CAPTURE = Path(__file__).resolve().parent / "data" / "egm_exchange.json"
MODEL = load_robot("abb_irb2400")


def raw_fields(data: bytes) -> dict[int, list]:
    """field number -> values, read without any schema."""
    m = empty_pb2.Empty()
    m.ParseFromString(data)
    out: dict[int, list] = {}
    for f in UnknownFieldSet(m):
        out.setdefault(f.field_number, []).append(f.data)
    return out


def test_the_schema_has_abbs_numbers():
    assert egm_schema.check_schema() == []
    assert egm_schema.egm_pb2 is egm_pb2


def test_droid_egm_replies_decode_with_the_official_classes():
    core = EgmCore(MODEL, 12, 60.0)
    q = [1.0, 2.0, 3.0, 4.0, 35.0, 6.0]
    core.datagram(robot_bytes(1, joints=q), CONTROLLER, 0)
    core.cycle(command(brain_tick=1, planner_tick=1, encoder_cmd_int=counts(MODEL, q)), MS)
    data, addr = core.datagram(robot_bytes(2, joints=q), CONTROLLER, 4 * MS)
    assert addr == CONTROLLER
    m = egm_pb2.EgmSensor()
    m.ParseFromString(data)
    assert m.header.mtype == egm_pb2.EgmHeader.MSGTYPE_CORRECTION and m.header.seqno == 2
    assert np.allclose(list(m.planned.joints.joints), q, atol=1e-3)
    assert list(m.speedRef.joints.joints) == [0.0] * 6 or len(m.speedRef.joints.joints) == 6
    # the same bytes without a schema: header = 1, planned = 2, speedRef = 3 (egm.proto's numbers)
    top = raw_fields(data)
    assert set(top) == {1, 2, 3}
    header = raw_fields(top[1][0])
    assert header[1] == [2] and header[3] == [egm_pb2.EgmHeader.MSGTYPE_CORRECTION]


def test_captured_exchange_decodes():
    log = json.loads(CAPTURE.read_text())["datagrams"]
    robot = [bytes.fromhex(d["hex"]) for d in log if d["dir"] == "robot->pc"]
    pc = [bytes.fromhex(d["hex"]) for d in log if d["dir"] == "pc->robot"]
    assert len(robot) >= 5 and len(pc) >= 5
    for k, data in enumerate(robot):
        m = egm_pb2.EgmRobot()
        m.ParseFromString(data)
        assert m.header.mtype == egm_pb2.EgmHeader.MSGTYPE_DATA and m.header.seqno == k + 1
        assert m.header.tm == 4 * k  # ms: every 4 ms of world time
        assert len(m.feedBack.joints.joints) == 6 and np.allclose(m.feedBack.joints.joints,
                                                                  [0, 10, 10, 0, 60, 0], atol=1.0)
        assert m.motorState.state == egm_pb2.EgmMotorState.MOTORS_ON
        assert m.rapidExecState.state == egm_pb2.EgmRapidCtrlExecState.RAPID_RUNNING
        assert m.mciState.state == egm_pb2.EgmMCIState.MCI_RUNNING
        assert len(m.testSignals.signals) == 6
        assert set(raw_fields(data)) == {1, 2, 3, 4, 5, 6, 7, 8}  # header..rapidExecState
    for k, data in enumerate(pc):
        m = egm_pb2.EgmSensor()
        m.ParseFromString(data)
        assert m.header.mtype == egm_pb2.EgmHeader.MSGTYPE_CORRECTION and m.header.seqno == k + 1
        assert len(m.planned.joints.joints) == 6
    # the last replies follow the way-point written after the second sample: toward +0.5 / -0.5 deg
    last = egm_pb2.EgmSensor()
    last.ParseFromString(pc[-1])
    assert last.planned.joints.joints[0] > 0.0 and last.planned.joints.joints[5] < 0.0


def test_captured_robot_datagrams_are_accepted_by_a_fresh_core():
    log = json.loads(CAPTURE.read_text())["datagrams"]
    core = EgmCore(MODEL, 12, 60.0)
    for d in log:
        if d["dir"] == "robot->pc":
            assert core.datagram(bytes.fromhex(d["hex"]), CONTROLLER, int(d["t_ms"] * MS)) is not None
    assert core.counters.accepted == sum(d["dir"] == "robot->pc" for d in log)
    assert core.counters.dropped == 0
