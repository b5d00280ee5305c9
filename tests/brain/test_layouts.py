"""Record layouts: fixed offsets, header checks (thesis Tables 3.1-3.3, 4.2-4.3)."""
import numpy as np
import pytest

from droid.brain.db import layouts as L
from droid.cli import BadInput


def test_thesis_field_names_present():
    for name in ("x", "y", "z", "R", "encoder_pos", "encoder_cmd", "busy", "homed"):
        assert name in L.ARM_STATUS.names and name in L.SENSOR_STATUS.names
    for name in ("x", "y", "z", "R", "cart_time_count", "encoder_pos", "joint_time_count",
                 "coord", "cmd_mode", "sent"):
        assert name in L.ARM_COMMAND.names
    for name in ("encoder_cmd_ext", "encoder_cmd_int", "joint_time_count", "coord", "cmd_mode"):
        assert name in L.CTRL_COMMAND.names


def test_controller_status_is_brain_status_layout():
    # Table 4.2: "the Status shared memory structure residing on the arm1 computer is identical"
    assert L.CTRL_STATUS == L.ARM_STATUS


@pytest.mark.parametrize("lay", list(L.LAYOUTS.values()), ids=lambda l: l.name)
def test_layout_is_little_endian_and_aligned(lay):
    assert lay.size % 8 == 0
    for name, (dt, off) in lay.dtype.fields.items():
        base = dt.subdtype[0] if dt.subdtype else dt
        assert base.byteorder in ("<", "|", "="), name
        if base.kind != "S":
            assert off % base.itemsize == 0, f"{lay.name}.{name} misaligned"
    assert lay.dtype.fields["seq"][1] == L.SEQ_OFFSET
    assert lay.dtype.fields["holder_pid"][1] == L.HOLDER_PID_OFFSET


def test_new_record_header_and_identity_rotation():
    rec = L.new_record(L.ARM_STATUS_LAYOUT)
    L.check_header(rec.tobytes(), L.ARM_STATUS_LAYOUT, "x")
    assert np.array_equal(rec["R"], np.eye(3))


@pytest.mark.parametrize("field,value,msg", [
    ("magic", 0x12345678, "bad magic"),
    ("kind", L.KIND_ARM_COMMAND, "holds a arm_command record"),
    ("version", 99, "layout version 99"),
    ("size", 8, "record size"),
])
def test_header_mismatch_refused(field, value, msg):
    rec = L.new_record(L.ARM_STATUS_LAYOUT)
    rec[field] = value
    with pytest.raises(L.LayoutError, match=msg) as ei:
        L.check_header(rec.tobytes(), L.ARM_STATUS_LAYOUT, "db")
    assert isinstance(ei.value, BadInput)


def test_short_buffer_refused():
    with pytest.raises(L.LayoutError, match="too short"):
        L.check_header(b"DRDB", L.ARM_STATUS_LAYOUT, "db")
