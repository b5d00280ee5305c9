"""Helpers of the ABB/EGM tests: EgmRobot datagrams built with the official generated classes
(abb-robot-client's egm_pb2), a controller Command record, virtual time."""
from __future__ import annotations

import numpy as np

from abb_robot_client._egm_protobuf import egm_pb2
from droid.brain.db.layouts import CTRL_COMMAND_LAYOUT, NORMAL_MODE, new_record

CONTROLLER = ("127.0.0.1", 40001)
MS = 1_000_000  # ns


def robot_bytes(seqno: int, joints=(0.0, 0.0, 0.0, 0.0, 30.0, 0.0), *, tm: int | None = None,
                mtype=egm_pb2.EgmHeader.MSGTYPE_DATA, motors=egm_pb2.EgmMotorState.MOTORS_ON,
                rapid=egm_pb2.EgmRapidCtrlExecState.RAPID_RUNNING, mci=egm_pb2.EgmMCIState.MCI_RUNNING,
                planned=None) -> bytes:
    m = egm_pb2.EgmRobot()
    m.header.seqno = seqno
    m.header.tm = (seqno * 4 if tm is None else tm) & 0xFFFFFFFF
    m.header.mtype = mtype
    m.feedBack.joints.joints.extend(joints)
    m.planned.joints.joints.extend(joints if planned is None else planned)
    m.motorState.state = motors
    m.rapidExecState.state = rapid
    m.mciState.state = mci
    m.mciConvergenceMet = True
    return m.SerializeToString()


def command(mode=NORMAL_MODE, **fields):
    rec = new_record(CTRL_COMMAND_LAYOUT)
    rec["cmd_mode"] = mode
    rec["link_alive"] = 1
    for k, v in fields.items():
        rec[k] = v
    return rec


def decode_sensor(data: bytes):
    m = egm_pb2.EgmSensor()
    m.ParseFromString(data)
    return m


def counts(model, joints_deg) -> np.ndarray:
    return np.rint(model.gearing.joints_to_counts(np.asarray(joints_deg, float))).astype(np.int32)
