"""ABB's EGM wire schema (``egm.proto``, package ``abb.egm``): the generated classes, one import.

EGM (Externally Guided Motion, ABB Application manual "Controller software IRC5/OmniCore",
section EGM) is protobuf over UDP: the robot controller sends ``EgmRobot`` (header, feedback
joints in degrees, planned joints, motor / RAPID / MCI state, convergence flag, test signals)
every 4 ms and takes ``EgmSensor`` (header, planned joint targets in degrees, speed references)
back.  We do not vendor ``egm.proto``: the generated classes come from the PyPI package
``abb-robot-client`` (Apache-2.0, Wason Technology / Rensselaer Polytechnic Institute), which
ships them, generated from ABB's schema, as ``abb_robot_client._egm_protobuf.egm_pb2``; this
module is the one place that names that path (pinned to abb-robot-client 0.4.x in
pyproject.toml).  :func:`check_schema` holds the schema to every field and enum value DROID
uses (tests/abb/test_egm_schema.py), so a changed package fails loudly, not on the wire.
"""
from __future__ import annotations

from abb_robot_client._egm_protobuf import egm_pb2  # noqa: F401 - re-exported
from google.protobuf.message import DecodeError  # noqa: F401 - re-exported

EgmRobot = egm_pb2.EgmRobot
EgmSensor = egm_pb2.EgmSensor
EgmHeader = egm_pb2.EgmHeader

MSGTYPE_DATA = EgmHeader.MSGTYPE_DATA  # robot -> sensor
MSGTYPE_CORRECTION = EgmHeader.MSGTYPE_CORRECTION  # sensor -> robot (joint/pose targets)
MOTORS_ON = egm_pb2.EgmMotorState.MOTORS_ON
MOTORS_OFF = egm_pb2.EgmMotorState.MOTORS_OFF
RAPID_RUNNING = egm_pb2.EgmRapidCtrlExecState.RAPID_RUNNING
RAPID_STOPPED = egm_pb2.EgmRapidCtrlExecState.RAPID_STOPPED
MCI_RUNNING = egm_pb2.EgmMCIState.MCI_RUNNING
MCI_STOPPED = egm_pb2.EgmMCIState.MCI_STOPPED
MCI_ERROR = egm_pb2.EgmMCIState.MCI_ERROR

#: (message, field, number) DROID reads or writes: ABB's numbers, which never change on the wire.
USED_FIELDS = (
    ("EgmHeader", "seqno", 1), ("EgmHeader", "tm", 2), ("EgmHeader", "mtype", 3),
    ("EgmJoints", "joints", 1),
    ("EgmPlanned", "joints", 1), ("EgmSpeedRef", "joints", 1),
    ("EgmFeedBack", "joints", 1),
    ("EgmRobot", "header", 1), ("EgmRobot", "feedBack", 2), ("EgmRobot", "planned", 3),
    ("EgmRobot", "motorState", 4), ("EgmRobot", "mciState", 5), ("EgmRobot", "mciConvergenceMet", 6),
    ("EgmRobot", "testSignals", 7), ("EgmRobot", "rapidExecState", 8),
    ("EgmSensor", "header", 1), ("EgmSensor", "planned", 2), ("EgmSensor", "speedRef", 3),
    ("EgmTestSignals", "signals", 1),
)
#: (enum, value name, number)
USED_ENUMS = (
    ("MessageType", "MSGTYPE_DATA", 2), ("MessageType", "MSGTYPE_CORRECTION", 3),
    ("MotorStateType", "MOTORS_ON", 1), ("MotorStateType", "MOTORS_OFF", 2),
    ("RapidCtrlExecStateType", "RAPID_STOPPED", 1), ("RapidCtrlExecStateType", "RAPID_RUNNING", 2),
    ("MCIStateType", "MCI_ERROR", 1), ("MCIStateType", "MCI_STOPPED", 2), ("MCIStateType", "MCI_RUNNING", 3),
)


def check_schema() -> list[str]:
    """Every field and enum value DROID uses, compared with the loaded schema; the differences
    (an empty list when the package ships ABB's numbers)."""
    wrong = []
    msgs = egm_pb2.DESCRIPTOR.message_types_by_name
    enums = {e.name: e for m in msgs.values() for e in m.enum_types}
    for msg, name, number in USED_FIELDS:
        f = msgs[msg].fields_by_name.get(name) if msg in msgs else None
        if f is None or f.number != number:
            wrong.append(f"{msg}.{name} = {number}")
    for enum, name, number in USED_ENUMS:
        v = enums[enum].values_by_name.get(name) if enum in enums else None
        if v is None or v.number != number:
            wrong.append(f"{enum}.{name} = {number}")
    if egm_pb2.DESCRIPTOR.package != "abb.egm":
        wrong.append("package abb.egm")
    return wrong
