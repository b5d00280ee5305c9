"""A failed command names its cause even when the fault that failed it has cleared (issue 16).

A servo silent for a few periods (a host stall) sets FAULT_SERVO; the planner fails the move in
progress; the servo's next status clears the bit.  droid-move / droid-seamtrack read the Status
after that, so the failure line must also name the faults seen while they waited."""
import pytest

from droid.brain.db import layouts as L
from droid.cli import RuntimeFailure
from droid.tasks.arm import BrainArm


class Sub:
    name = "arm1"


class FakeArm:
    """Just enough of a BrainArm for wait_done: Status records in turn, never stale."""

    def __init__(self, records):
        self.sub, self.records, self.live_cmd = Sub(), list(records), 5

    def read(self):
        return self.records.pop(0) if len(self.records) > 1 else self.records[0]

    wait = BrainArm.wait
    wait_finished = BrainArm.wait_finished
    check_result = BrainArm.check_result


def status(cmd_id, busy, result, fault=0):
    st = L.new_record(L.CTRL_STATUS_LAYOUT)
    st["cmd_id"], st["busy"], st["cmd_result"], st["fault"] = cmd_id, busy, result, fault
    return st


def test_a_fault_that_cleared_is_named():
    arm = FakeArm([status(5, 1, L.CMD_OK), status(5, 1, L.CMD_OK, L.FAULT_SERVO),
                   status(5, 0, L.CMD_FAILED)])
    with pytest.raises(RuntimeFailure, match=r"^arm1 failed command 5 \(faults while it ran, clear since: servo\)$"):
        BrainArm.wait_done(arm, 5, 5.0)
    assert arm.live_cmd is None


def test_a_fault_still_set_is_named_as_before():
    arm = FakeArm([status(5, 1, L.CMD_OK, L.FAULT_BRAKING), status(5, 0, L.CMD_FAILED, L.FAULT_WATCHDOG)])
    with pytest.raises(RuntimeFailure, match=r"^arm1 failed command 5 \(faults: watchdog\)$"):
        BrainArm.wait_done(arm, 5, 5.0)


def test_no_fault_seen_no_parenthesis_and_success_is_quiet():
    arm = FakeArm([status(5, 0, L.CMD_FAILED)])
    with pytest.raises(RuntimeFailure, match=r"^arm1 failed command 5$"):
        BrainArm.wait_done(arm, 5, 5.0)
    ok = FakeArm([status(5, 1, L.CMD_OK, L.FAULT_SERVO), status(5, 0, L.CMD_OK)])
    assert int(BrainArm.wait_done(ok, 5, 5.0)["cmd_id"]) == 5
