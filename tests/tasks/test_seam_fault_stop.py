"""The seam tracker stops on an arm fault (issue 16 item 2: nothing runs away, every failure
names its cause).

The rule is droid.tasks.seam.cycle's (``arm_faults``, ``TrackingCycle.check_faults``), shared by
droid-seamtrack and the lockstep trial.  Here: the rule itself, and droid-seamtrack's cycle, loop
and main with fake Status records (no cell, no processes).  The lockstep trial with a fault
injected into the full Reis: tests/sim/test_trial_fault_stop.py.
"""
from __future__ import annotations

import csv
from types import SimpleNamespace

import numpy as np
import pytest

from droid.brain.cell.cellfile import builtin_cell_path, load_cell
from droid.brain.db.layouts import (ARM_STATUS, FAULT_BRAKING, FAULT_DEVICE, FAULT_HEARTBEAT, FAULT_LIMIT,
                                 FAULT_LINK, FAULT_SERVO, FAULT_WATCHDOG, FAULTS_CANNOT_MOVE, SENSOR_STATUS,
                                 FAULT_COLLISION, FAULTS_STOP_RUN)
from droid.cli import EXIT_RUNTIME, RuntimeFailure
from droid.tasks import seamtrack
from droid.tasks.seam.params import MODES, SeamParams
from droid.tasks.seam.stops import STOP_FAULT
from droid.tasks.seam.cycle import TrackingCycle, arm_faults
from droid.tasks.seam.delay import INVALID_READING
from droid.brain.cell.cell_layout import load_layout

LAYOUT = load_layout()
WRIST = LAYOUT.wrist("standard")


# -- the shared rule ---------------------------------------------------------------------------
def test_no_fault_or_a_fault_the_arm_still_moves_with_does_not_stop():
    assert arm_faults([("arm1", 0), ("gmf1", 0)]) is None
    # link / heartbeat go with a stale Status (the stale rule); limit: a clamped target
    for bits in (FAULT_LINK, FAULT_HEARTBEAT, FAULT_LIMIT, FAULT_LINK | FAULT_HEARTBEAT | FAULT_LIMIT):
        assert arm_faults([("arm1", bits), ("gmf1", bits)]) is None, bits


@pytest.mark.parametrize("bit, name", [(FAULT_BRAKING, "braking"), (FAULT_COLLISION, "collision")])
def test_a_protective_stop_ends_the_run_and_is_named(bit, name):
    """Issue 40 item 4: the arm could follow again at the next command, but the weld slowed or
    stopped where it braked -- a defect the run must not ride through."""
    assert bit & FAULTS_STOP_RUN and not bit & FAULTS_CANNOT_MOVE
    assert arm_faults([("arm1", bit), ("gmf1", 0)]) == f"arm1 faults: {name}"
    assert arm_faults([("arm1", bit | FAULT_LIMIT), ("gmf1", 0)]) == f"arm1 faults: limit, {name}"


@pytest.mark.parametrize("bit, name", [(FAULT_SERVO, "servo"), (FAULT_WATCHDOG, "watchdog"),
                                       (FAULT_DEVICE, "device")])
def test_each_fault_the_arm_cannot_move_with_stops_and_is_named(bit, name):
    assert bit & FAULTS_CANNOT_MOVE
    assert arm_faults([("arm1", bit), ("gmf1", 0)]) == f"arm1 faults: {name}"
    assert arm_faults([("arm1", 0), ("gmf1", bit)]) == f"gmf1 faults: {name}"


def test_the_detail_names_every_fault_bit_of_every_faulted_arm():
    # trial 2.5's Reis: Status fault 20 (servo + braking), then 22 (+ watchdog)
    assert arm_faults([("arm1", 20), ("gmf1", 0)]) == "arm1 faults: servo, braking"
    assert arm_faults([("arm1", 22), ("gmf1", 0)]) == "arm1 faults: watchdog, servo, braking"
    assert arm_faults([("arm1", np.uint32(FAULT_WATCHDOG)), ("gmf1", FAULT_DEVICE | FAULT_LINK)]) == \
        "arm1 faults: watchdog; gmf1 faults: link, device"


@pytest.mark.parametrize("mode", MODES)
def test_check_faults_stops_the_core_for_good_and_the_first_stop_stays(mode):
    cyc = TrackingCycle(SeamParams(16.0, mode=mode), WRIST.T_wcp_tool, WRIST.T_wcp_sensor)
    assert cyc.check_faults([("arm1", FAULT_LIMIT), ("gmf1", 0)]) is None
    assert cyc.stopped is None
    stop = cyc.check_faults([("arm1", FAULT_SERVO | FAULT_BRAKING), ("gmf1", 0)])
    assert stop is not None and stop is cyc.stopped
    assert (stop.reason, stop.detail) == (STOP_FAULT, "arm1 faults: servo, braking")
    assert str(stop) == "fault at 0.0 mm (arm1 faults: servo, braking)"
    # the fault clears (a restarted servo): the run stays stopped, no command comes out
    I = np.eye(4)
    out = cyc.step(I, I, 10, INVALID_READING, 9)
    assert out.tool_cmd is None and out.hold_cmd is None and out.stop is stop
    later = cyc.check_faults([("arm1", 0), ("gmf1", FAULT_DEVICE)])
    assert later is stop and later.detail == "arm1 faults: servo, braking"


# -- droid-seamtrack with fake Status records ------------------------------------------------
class FakeDb:
    """A Status database whose record is ``make()``'s, read at the fake clock's tick."""

    def __init__(self, make) -> None:
        self.make = make

    def read(self):
        return self.make()


def _arm_record(T, counts=None, tick=0, fault=0):
    rec = np.zeros((), ARM_STATUS)
    rec["R"] = T[:3, :3]
    rec["x"], rec["y"], rec["z"] = T[:3, 3]
    if counts is not None:
        rec["encoder_pos"] = counts
    rec["homed"] = 1
    rec["tick"] = tick
    rec["fault"] = fault
    return rec


class Fake:
    """The records of a standing cell at position (i); ``faults[name] = (from_tick, bits)``."""

    def __init__(self, tr) -> None:
        self.tick = 0
        self.faults: dict[str, tuple[int, int]] = {}
        self.commands: list[tuple[str, int]] = []  # (arm, tick) of every command written
        self.T_reis, self.T_hold = LAYOUT.start_poses("i", "standard")
        q = tr.tool_robot.model.ik(self.T_reis, np.zeros(6))
        self.counts = np.rint(tr.tool_robot.model.gearing.joints_to_counts(q)).astype(np.int32)

    def bits(self, name: str) -> int:
        start, bits = self.faults.get(name, (None, 0))
        return bits if start is not None and self.tick >= start else 0

    def install(self, tr) -> None:
        tr.tool_robot.status = FakeDb(lambda: _arm_record(self.T_reis, self.counts, self.tick, self.bits("arm1")))
        tr.hold.status = FakeDb(lambda: _arm_record(self.T_hold, None, self.tick, self.bits("gmf1")))
        lead = np.zeros((), SENSOR_STATUS)
        lead["homed"] = 1  # no seam in view: an invalid reading (the dead zone does not read it)
        tr.lead_db = FakeDb(lambda: lead.copy())
        tr.tool_db = None
        tr.tool_robot.command_cart = lambda T, ticks: self.commands.append(("arm1", self.tick))
        tr.hold.command_cart = lambda T, ticks: self.commands.append(("gmf1", self.tick))


class FakeTicks:
    """The heartbeat: ticks 1, 2, ... at 60 Hz; moves the fake clock."""

    def __init__(self, fake: Fake, period_ns: int, last: int = 600) -> None:
        self.fake, self.period_ns, self.last = fake, period_ns, last

    def wait(self, timeout_s):
        self.fake.tick += 1
        if self.fake.tick > self.last:
            raise AssertionError("the tracker did not stop")
        return SimpleNamespace(tick=self.fake.tick, t_ns=self.fake.tick * self.period_ns)


#: The fake lead sensor sees no seam: a lost-seam limit longer than the fakes' runs.
NEVER_LOST = ("--lost-cycles", "10000")


def _tracker(*argv):
    cell = load_cell(builtin_cell_path())
    args = seamtrack.build_parser().parse_args(["16", "--quiet", *NEVER_LOST, *argv])
    tr = seamtrack.Tracker(args, cell, LAYOUT)
    return tr, Fake(tr)


def test_cycle_writes_commands_until_an_arm_faults_and_none_after():
    tr, fake = _tracker()
    fake.install(tr)
    fake.tick = 1
    assert tr.on_tick(fake.tick) is None
    assert fake.commands == [("arm1", 1), ("gmf1", 1)]  # the Reis step and the GMF1's one hold
    fake.tick = 3
    fake.faults["arm1"] = (3, FAULT_LIMIT)  # a clamped target: the tracker goes on
    assert tr.on_tick(fake.tick) is None
    assert fake.commands[-1] == ("arm1", 3)
    fake.tick = 5
    fake.faults["arm1"] = (5, FAULT_BRAKING)  # a protective stop: the run ends
    why = tr.on_tick(fake.tick)
    assert why == "fault at 0.0 mm (arm1 faults: braking)"
    assert tr.core.stopped.reason == STOP_FAULT
    assert fake.commands[-1] == ("arm1", 3)
    fake.tick = 7
    fake.faults.clear()
    tr.on_tick(fake.tick)  # cleared again: still stopped, nothing written
    assert fake.commands[-1] == ("arm1", 3)


def test_a_holder_fault_stops_the_run_naming_the_holder():
    tr, fake = _tracker()
    fake.install(tr)
    fake.faults["gmf1"] = (0, FAULT_DEVICE)
    fake.tick = 1
    assert tr.on_tick(fake.tick) == "fault at 0.0 mm (gmf1 faults: device)"
    assert fake.commands == []


def test_the_loop_exits_1_within_one_cycle_of_the_fault_and_commands_nothing_after():
    tr, fake = _tracker()
    fake.install(tr)
    fault_tick = 95  # after the dead zone's 30 cycles; an odd tick: between two cycles
    fake.faults["arm1"] = (fault_tick, FAULT_WATCHDOG | FAULT_SERVO | FAULT_BRAKING)
    code, why = tr._loop(FakeTicks(fake, tr.cell.period_ns))
    assert code == EXIT_RUNTIME == 1
    assert why.startswith("fault at ") and why.endswith("(arm1 faults: watchdog, servo, braking)"), why
    assert len(fake.commands) > 40  # it tracked before
    assert max(t for _, t in fake.commands) < fault_tick
    stopped_at = fake.tick
    assert 0 <= stopped_at - fault_tick < tr.cyc.cycle_ticks  # the first cycle that saw the Status


def _main_with_fakes(monkeypatch, fault: tuple[str, int, int], *argv):
    """droid-seamtrack's main() on the fakes: (arm, from tick, bits) of the fault."""
    seen = {}

    class FakeTracker(seamtrack.Tracker):
        def connect(self):
            fake = Fake(self)
            fake.install(self)
            fake.faults[fault[0]] = (fault[1], fault[2])
            seen["fake"], seen["tr"] = fake, self

        def close(self):
            pass

        def run(self):
            return self._loop(FakeTicks(seen["fake"], self.cell.period_ns))

    monkeypatch.setattr(seamtrack, "Tracker", FakeTracker)
    monkeypatch.setattr(seamtrack, "open_cell", lambda args: load_cell(args.cell))  # no priority ceiling
    monkeypatch.setattr(seamtrack.Stop, "install", classmethod(lambda cls: None))
    code = seamtrack.main(["16", "--quiet", *NEVER_LOST, "--cell", str(builtin_cell_path()), *argv])
    return code, seen


def test_main_exits_1_with_one_line_naming_the_arm_and_writes_the_log_and_summary(monkeypatch, capsys, tmp_path):
    log = tmp_path / "run.csv"
    code, seen = _main_with_fakes(monkeypatch, ("arm1", 125, FAULT_SERVO | FAULT_BRAKING), "--log", str(log))
    out, err = capsys.readouterr()
    assert code == 1
    assert err.strip().splitlines() == ["droid-seamtrack: stopped: fault at 0.0 mm (arm1 faults: servo, braking)"]
    assert "fault" in out.splitlines()[0]  # the summary line says how the run ended
    assert f"log: {log}" in out
    with open(log, newline="") as f:
        rows = list(csv.reader(f))
    assert len(rows) > 10  # the header and the 10 Hz rows until the fault
    assert max(t for _, t in seen["fake"].commands) < 125


def test_a_fault_before_tracking_refuses_to_start_and_nothing_is_written(monkeypatch, capsys):
    code, seen = _main_with_fakes(monkeypatch, ("arm1", 0, FAULT_WATCHDOG))
    _, err = capsys.readouterr()
    assert code == 1
    assert err.startswith("droid-seamtrack: arm1 cannot move: fault watchdog") and len(err.splitlines()) == 1
    assert seen["fake"].commands == [] and seen["fake"].tick == 0  # refused before the first tick


def test_check_ready_names_a_holder_fault(monkeypatch):
    tr, fake = _tracker()
    fake.install(tr)
    fake.faults["gmf1"] = (0, FAULT_DEVICE)
    with pytest.raises(RuntimeFailure, match="gmf1 cannot move: fault device"):
        tr.check_ready()
