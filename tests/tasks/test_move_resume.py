"""A task's positioning move rides through a protective stop (issue 40 item 4; droid.tasks.resume,
BrainArm.move).

The decisions alone (pure), then BrainArm.move end to end against a small fake arm: the
Brain's Status and Command records in memory, the real planner (droid.arm.planner:
it cancels a move with CMD_FAILED when FAULT_BRAKING shows and takes no new one while it
does), a servo that follows the planner's way-point, and scripted stops -- on a virtual
clock, so no test waits in real time and none gives a verdict on timing.  The live test:
tests/tasks/test_move_resume_cell.py.
"""
from __future__ import annotations

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from droid.brain.db import layouts as L
from droid.brain.cell.cellfile import builtin_cell_path, load_cell
from droid.brain.cell.classes import ARM6R
from droid.brain.db.shmdb import MemoryDatabase
from droid.cli import RuntimeFailure
from droid.kinematics.transforms import T_to_pose
from droid.arm.planner import PlannerCore, apply
from droid.tasks import arm as arm_mod
from droid.tasks import resume as rs
from droid.tasks.arm import BrainArm, Interrupted

CELL = load_cell(builtin_cell_path())
HZ = CELL.heartbeat_hz
LINE = re.compile(r"^arm1: protective stop at (\d+) % of the move \(braking\); "
                  r"resuming from the arm's position \((\d) of 3\)$")


# -- the decisions ------------------------------------------------------------------------------
def test_only_braking_alone_on_a_failed_move_is_a_protective_stop():
    assert rs.protective_stop(L.CMD_FAILED, L.FAULT_BRAKING)
    assert not rs.protective_stop(L.CMD_OK, L.FAULT_BRAKING)  # done: nothing to resume
    assert not rs.protective_stop(L.CMD_REFUSED, L.FAULT_BRAKING)
    assert not rs.protective_stop(L.CMD_FAILED, 0)  # failed, no braking seen: not ours to judge
    for bit in (L.FAULT_SERVO, L.FAULT_WATCHDOG, L.FAULT_LIMIT, L.FAULT_FORCE, L.FAULT_DEVICE,
                L.FAULT_LINK, L.FAULT_HEARTBEAT, 1 << 12):  # 1 << 12: a bit a later layout adds
        assert not rs.protective_stop(L.CMD_FAILED, L.FAULT_BRAKING | bit), bit
        assert rs.RestWatch.hard(bit | L.FAULT_BRAKING), bit
    assert rs.RestWatch.hard(L.FAULT_BRAKING) is None
    assert rs.RestWatch.hard(L.FAULT_SERVO | L.FAULT_WATCHDOG | L.FAULT_BRAKING) == "watchdog, servo"
    assert rs.RestWatch.hard(L.FAULT_SERVO | 1 << 12) == "servo, 0x1000"


def test_progress_is_the_share_of_the_joint_space_line_clamped():
    a, b = np.zeros(6), np.array([10.0, -20.0, 0, 0, 0, 5.0])
    assert rs.progress(a, b, a) == 0.0 and rs.progress(a, b, b) == 1.0
    assert rs.progress(a, b, 0.41 * b) == pytest.approx(0.41)
    assert rs.progress(a, b, 0.5 * b + np.array([0, 0, 3.0, 0, 0, 0])) == pytest.approx(0.5)  # off the line
    assert rs.progress(a, b, -b) == 0.0 and rs.progress(a, b, 2 * b) == 1.0
    assert rs.progress(b, b, a) == 1.0  # a move of no length


def test_the_resumed_duration_keeps_the_average_speed_and_is_never_faster():
    rng = np.random.default_rng(40)
    vmax = np.array([100.0, 100, 100, 200, 200, 200])
    for _ in range(500):
        a, b = rng.uniform(-90, 90, 6), rng.uniform(-90, 90, 6)
        seconds = float(rng.uniform(0.2, 20.0))
        now = a + rng.uniform(0, 1) * (b - a) + rng.normal(0, 0.05, 6)  # near the line (braking)
        t = rs.resumed_seconds(a, b, seconds, now, b, vmax, 3600.0)
        v0 = np.linalg.norm(b - a) / seconds
        assert np.linalg.norm(b - now) / t <= v0 * (1 + 1e-9)  # never faster (joint space)
        assert np.all(np.abs(b - now) / t <= vmax * (1 + 1e-9))  # within the speed limits
        ticks = rs.resumed_ticks(t, HZ)
        assert ticks >= 1 and ticks / HZ >= t - 1e-9  # rounded up, not down
    # exactly the remaining share of the time on the line, when the speed limits allow it
    a, b = np.zeros(6), np.array([20.0, 0, 0, 0, 0, 0])
    assert rs.resumed_seconds(a, b, 4.0, 0.25 * b, b, vmax, 3600.0) == pytest.approx(3.0)
    # the speed limits win over a fast original (20 deg at 100 deg/s: 0.2 s)
    assert rs.resumed_seconds(a, b, 0.01, a, b, vmax, 3600.0) == pytest.approx(0.2)
    assert rs.resumed_seconds(a, a, 2.0, a, a + 0.01, vmax, 3600.0) == 2.0  # a move of no length
    assert rs.resumed_ticks(1e-6, HZ) == 1 and rs.resumed_ticks(0.5, HZ) == 30 and rs.resumed_ticks(0.501, HZ) == 31


def test_the_lines():
    assert rs.resume_line("arm1", 0.414, L.FAULT_BRAKING, 1) == \
        "arm1: protective stop at 41 % of the move (braking); resuming from the arm's position (1 of 3)"
    assert rs.arrived_line("arm1", 1) == "arm1: arrived after 1 resume"
    assert rs.arrived_line("gmf1", 2) == "gmf1: arrived after 2 resumes"
    assert rs.summary_note(0) == ""
    assert rs.summary_note(3) == "; start moves: 3 resumes after a protective stop"


def test_the_resumer_allows_three_resumes_and_none_when_off():
    job = rs.Resumer("arm1", np.zeros(6), np.ones(6), 2.0)
    for n in range(1, 4):
        assert job.refusal(L.CMD_FAILED, L.FAULT_BRAKING) is None
        assert LINE.match(job.next_line(np.full(6, 0.5), L.FAULT_BRAKING)).group(2) == str(n)
    assert "not resumed again (at most 3 resumes)" in job.refusal(L.CMD_FAILED, L.FAULT_BRAKING)
    assert job.refusal(L.CMD_OK, 0) == ""
    off = rs.Resumer("arm1", np.zeros(6), np.ones(6), 2.0, enabled=False)
    assert off.refusal(L.CMD_FAILED, L.FAULT_BRAKING) == ""  # --no-resume: reported as ever


def test_rest_needs_records_of_newer_ticks_still_and_without_braking():
    w = rs.RestWatch()
    pos = np.zeros(6, np.int64)
    assert not w.at_rest(1, pos, L.FAULT_BRAKING)
    assert not w.at_rest(2, pos, 0)
    assert not w.at_rest(3, pos + 2, 0)  # 2 counts: still
    assert not w.at_rest(3, pos + 2, 0)  # the same tick again counts once
    assert w.at_rest(4, pos + 1, 0)
    w = rs.RestWatch()
    for t in range(1, 10):  # moving 3 counts a tick: never at rest
        assert not w.at_rest(t, pos + 3 * t, 0)
    assert not w.at_rest(10, pos + 27, L.FAULT_BRAKING)  # braking again resets the count
    assert not w.at_rest(11, pos + 27, 0) and not w.at_rest(12, pos + 27, 0) and w.at_rest(13, pos + 27, 0)


# -- BrainArm.move against a fake arm ------------------------------------------------------------
class Clock:
    """Virtual time for droid.tasks.arm's waits: sleep() advances it."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += dt


class FakeArm:
    """The Brain's records of one arm and what drives them, a heartbeat tick at a time.

    ``stops``: scripted protective stops, consumed in order, each (leg tick, extra fault bits,
    braking ticks): at that tick of the command in progress the servo brakes (FAULT_BRAKING,
    with the extra bits) for so many ticks, drifting ``drift_counts`` per tick, less each
    tick; ``hard_after``: (ticks after a stop, bits) that stay set from then (a hard fault
    found at the resume); ``brake_forever``: the braking fault never clears."""

    def __init__(self, model, clock: Clock, start_counts, stops=(), drift_counts: float = 0.0,
                 hard_after=None, brake_forever: bool = False) -> None:
        self.clock, self.model = clock, model
        self.status = MemoryDatabase("arm1.status", L.ARM_STATUS_LAYOUT)
        self.command = MemoryDatabase("arm1.command", L.ARM_COMMAND_LAYOUT)
        self.ctrl_status = MemoryDatabase("arm1.ctrl_status", L.CTRL_STATUS_LAYOUT)
        self.ctrl_command = MemoryDatabase("arm1.ctrl_command", L.CTRL_COMMAND_LAYOUT)
        self.ctrl_command.update(cmd_mode=L.NORMAL_MODE, link_alive=1)
        self.planner = PlannerCore(model)
        self.pos = np.asarray(start_counts, float)
        self.stops, self.drift, self.hard_after, self.brake_forever = list(stops), drift_counts, hard_after, brake_forever
        self.tick = 0
        self.leg_id, self.leg_tick = None, 0
        self.braking, self.v, self.extra, self.hard, self.since_stop = 0, 0.0, 0, 0, None
        self.commands = []  # (cmd_id, coord, joint_time_count, cart_time_count) of each command taken in
        self.taken_at = []  # ... and the arm's position then [counts]
        self.cancels = []  # the position [counts] at each protective stop
        self._copy()
        for _ in range(3):  # the planner runs before any task writes (it holds where the arm is)
            clock.sleep(1.0 / HZ)
            self.step()

    # what BrainArm reads as its Status record (each read lets the arm catch up to the clock)
    def read(self):
        while self.tick < math.floor(self.clock.t * HZ):
            self.step()
        return self.status.read()

    def close(self) -> None:
        pass

    def _copy(self) -> None:
        rec = self.ctrl_status.read()
        self.status.update(tick=self.tick, stale=0, **{k: rec[k] for k in ARM6R.copy_fields})

    def step(self) -> None:
        self.tick += 1
        c = self.command.read()
        if int(c["sent"]):  # the remote and the agent deliver the Brain command
            fields = {dst: c[src] for src, dst in ARM6R.command_map.items() if src != "sent"}
            self.ctrl_command.update(**fields)
            self.command.update(sent=0)
            self.commands.append((int(c["cmd_id"]), int(c["coord"]), int(c["joint_time_count"]),
                                  int(c["cart_time_count"])))
            self.taken_at.append(self.pos.copy())
        self.ctrl_command.update(brain_tick=self.tick)
        self._fault_script()
        faults = (L.FAULT_BRAKING | self.extra if self.braking else 0) | self.hard
        self.ctrl_status.update(encoder_pos=np.rint(self.pos).astype(np.int32), homed=L.HOMED, fault=faults)
        out = self.planner.step(self.ctrl_command.read(), self.ctrl_status.read())
        apply(out, self.ctrl_command, self.ctrl_status, self.tick)
        if self.braking:  # the servo brakes: its own profile, not the way-points
            self.pos = self.pos + self.v
            self.v *= 0.5
            self.braking = self.braking if self.brake_forever else self.braking - 1
        else:
            self.pos = np.asarray(self.ctrl_command.read()["encoder_cmd_int"], float)
        self._copy()

    def _fault_script(self) -> None:
        st = self.ctrl_status.read()
        if int(st["busy"]) > 0 and int(st["cmd_id"]) != self.leg_id:
            self.leg_id, self.leg_tick = int(st["cmd_id"]), 0
        self.leg_tick += 1
        if self.since_stop is not None:
            self.since_stop += 1
            if self.hard_after is not None and self.since_stop >= self.hard_after[0]:
                self.hard = self.hard_after[1]
        if self.stops and not self.braking and int(st["busy"]) > 0 and self.leg_tick >= self.stops[0][0]:
            _, self.extra, self.braking = self.stops.pop(0)
            direction = np.sign(np.asarray(self.ctrl_command.read()["encoder_cmd_ext"], float) - self.pos)
            self.v = direction * self.drift
            self.cancels.append(self.pos.copy())
            self.since_stop = 0


START = np.array([0, 0, 0, 0, 0, 0])
GOAL = np.array([100000, -20000, 30000, 0, 0, 50000])  # 90 deg on joint 1: >= 0.9 s at its limit


@pytest.fixture
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(arm_mod, "time", SimpleNamespace(monotonic=c.monotonic, sleep=c.sleep))
    return c


def brain_arm(clock, **kw):
    arm = BrainArm(CELL, "arm1")
    fake = FakeArm(arm.model, clock, kw.pop("start", START), **kw)
    arm.status, arm.command = fake, fake.command
    return arm, fake


def said():
    lines = []
    return lines, lines.append


def test_a_move_without_a_stop_says_nothing_and_arrives(clock):
    arm, fake = brain_arm(clock)
    lines, say = said()
    assert arm.move("joint", GOAL, 2.0, say=say) == 0
    assert lines == [] and len(fake.commands) == 1 and fake.commands[0][2] == 120
    assert np.all(np.abs(fake.pos - GOAL) <= 1)


def test_a_protective_stop_is_resumed_once_from_where_the_arm_stopped(clock):
    arm, fake = brain_arm(clock, stops=[(50, 0, 6)], drift_counts=400.0)
    lines, say = said()
    assert arm.move("joint", GOAL, 2.0, say=say) == 1
    assert len(lines) == 1 and LINE.match(lines[0]) and LINE.match(lines[0]).group(2) == "1", lines
    # the percentage is where the arm came to rest along the joint-space line
    q0, q1 = (arm.model.gearing.counts_to_joints(np.asarray(v, float)) for v in (START, GOAL))
    rest = arm.model.gearing.counts_to_joints(fake.taken_at[1])
    want = round(100 * rs.progress(q0, q1, rest))
    assert int(LINE.match(lines[0]).group(1)) == want and 35 <= want <= 50
    # re-issued toward the same target, never faster than the original
    first, again = fake.commands
    assert again[0] == first[0] + 1 and again[1] == L.JSPACE
    assert np.asarray(fake.ctrl_command.read()["encoder_cmd_ext"]).tolist() == GOAL.tolist()
    frac_left = np.linalg.norm(q1 - rest) / np.linalg.norm(q1 - q0)
    assert again[2] >= math.floor(120 * frac_left) and again[2] / HZ >= 2.0 * frac_left - 1e-9
    assert np.all(np.abs(fake.pos - GOAL) <= 1)  # arrived (move() checked it too)
    assert arm.live_cmd is None


def test_three_resumes_then_a_fourth_stop_fails_naming_it(clock):
    arm, fake = brain_arm(clock, stops=[(40, 0, 4), (10, 0, 4), (10, 0, 4), (10, 0, 4)])
    lines, say = said()
    with pytest.raises(RuntimeFailure, match=r"^arm1 failed command 4 \(faults(?: while it ran, clear since)?: "
                                             r"braking\): protective stop 4 times, not resumed again "
                                             r"\(at most 3 resumes\)$"):
        arm.move("joint", GOAL, 2.0, say=say)
    assert [LINE.match(ln).group(2) for ln in lines] == ["1", "2", "3"]
    pct = [int(LINE.match(ln).group(1)) for ln in lines]
    assert pct == sorted(pct) and pct[0] > 0  # along the whole move, each stop farther
    assert len(fake.commands) == 4 and arm.live_cmd is None


@pytest.mark.parametrize("bit, name", [(L.FAULT_SERVO, "servo"), (L.FAULT_WATCHDOG, "watchdog"),
                                       (L.FAULT_FORCE, "force"), (L.FAULT_LIMIT, "limit"),
                                       (L.FAULT_DEVICE, "device")])
def test_a_stop_with_a_hard_fault_is_not_resumed_and_names_it(clock, bit, name):
    arm, fake = brain_arm(clock, stops=[(50, bit, 5)])
    lines, say = said()
    with pytest.raises(RuntimeFailure, match=rf"^arm1 failed command 1 \(faults(?: while it ran, clear since)?: "
                                             rf"[a-z, ]*\b{name}\b[a-z, ]*\)$"):
        arm.move("joint", GOAL, 2.0, say=say)
    assert lines == [] and len(fake.commands) == 1


@pytest.mark.parametrize("bit, name", [(L.FAULT_SERVO, "servo"), (L.FAULT_WATCHDOG, "watchdog")])
def test_a_hard_fault_found_at_the_resume_is_not_resumed(clock, bit, name):
    arm, fake = brain_arm(clock, stops=[(50, 0, 8)], hard_after=(6, bit))
    lines, say = said()
    with pytest.raises(RuntimeFailure, match=rf"^arm1: protective stop at \d+ % of the move, then fault {name}: "
                                             r"not resumed$"):
        arm.move("joint", GOAL, 2.0, say=say)
    assert lines == [] and len(fake.commands) == 1


def test_no_resume_fails_as_today(clock):
    arm, fake = brain_arm(clock, stops=[(50, 0, 5)])
    lines, say = said()
    with pytest.raises(RuntimeFailure, match=r"^arm1 failed command 1 \(faults(?: while it ran, clear since)?: "
                                             r"braking\)$"):
        arm.move("joint", GOAL, 2.0, resume=False, say=say)
    assert lines == [] and len(fake.commands) == 1
    assert np.any(np.abs(fake.pos - GOAL) > 10000)  # it stopped where the stop left it


def test_an_arm_that_keeps_braking_is_not_resumed_after_five_seconds(clock):
    arm, fake = brain_arm(clock, stops=[(50, 0, 1)], brake_forever=True)
    lines, say = said()
    with pytest.raises(RuntimeFailure, match=r"^timed out after 5 s waiting for arm1 to come to rest with its "
                                             r"braking fault clear after a protective stop \(not resumed\)$"):
        arm.move("joint", GOAL, 2.0, say=say)
    assert lines == [] and len(fake.commands) == 1
    assert 5.0 < clock.t < 2.0 + 5.0 + 0.5  # the move until its stop, then 5 s


def test_a_cartesian_move_is_resumed_toward_the_same_pose(clock):
    arm, fake = brain_arm(clock, stops=[(60, 0, 5)], drift_counts=100.0,
                          start=np.array([10000, -5000, 8000, 2000, 3000, 1000]))
    q0 = arm.model.gearing.counts_to_joints(np.array([10000, -5000, 8000, 2000, 3000, 1000], float))
    q_goal = q0 + np.array([20.0, 10.0, -10.0, 5.0, -5.0, 10.0])
    pose = T_to_pose(arm.model.fk(q_goal))
    lines, say = said()
    assert arm.move("cart", pose, 3.0, say=say) == 1
    assert len(lines) == 1 and LINE.match(lines[0])
    assert [c[1] for c in fake.commands] == [L.CARTSPACE, L.CARTSPACE]
    assert fake.commands[1][3] < fake.commands[0][3]  # the rest of the way, in fewer ticks
    assert np.max(np.abs(arm.joints_deg() - q_goal)) <= arm_mod.ARRIVAL_TOL_DEG


def test_interrupted_while_waiting_for_rest_writes_no_new_command(clock):
    arm, fake = brain_arm(clock, stops=[(50, 0, 30)])
    with pytest.raises(Interrupted):
        arm.move("joint", GOAL, 2.0, say=lambda _: None, interrupted=lambda: bool(fake.cancels))
    assert len(fake.commands) == 1  # no resume, nothing else


def test_interrupted_during_the_resumed_move_stops_it_where_the_arm_stands(clock):
    arm, fake = brain_arm(clock, stops=[(50, 0, 5)])
    with pytest.raises(Interrupted):
        arm.move("joint", GOAL, 2.0, say=lambda _: None, interrupted=lambda: len(fake.commands) >= 2)
    for _ in range(10):
        fake.step()
    resumed, stop = fake.commands[1], fake.commands[2]
    assert stop[0] == resumed[0] + 1 and stop[2] == L.STOP_TICKS and stop[3] == L.STOP_TICKS
    assert arm.live_cmd is None and arm.stopped_cmd == stop[0]
    still = fake.pos.copy()
    for _ in range(30):
        fake.step()
    assert np.all(np.abs(fake.pos - still) <= 1) and np.any(np.abs(fake.pos - GOAL) > 1000)


def test_a_timeout_during_a_resumed_move_stops_it_too(clock):
    arm, fake = brain_arm(clock, stops=[(50, 0, 5)])
    with pytest.raises(RuntimeFailure, match="timed out after 0.3 s waiting for arm1 to finish command 2"):
        arm.move("joint", GOAL, 2.0, say=lambda _: None, timeout=lambda s: 0.3 if s < 2.0 else 10.0)
    fake.step()
    assert len(fake.commands) == 3 and fake.commands[-1][2] == L.STOP_TICKS and arm.stopped_cmd == fake.commands[-1][0]


# -- the programs ----------------------------------------------------------------------------
def test_the_start_move_of_seamtrack_and_contact_resumes_and_counts(clock, monkeypatch, capsys):
    from droid.tasks import seamtrack

    monkeypatch.setattr(seamtrack, "time", SimpleNamespace(monotonic=clock.monotonic, sleep=clock.sleep))
    monkeypatch.setattr(seamtrack.Stop, "requested", False)
    arm, fake = brain_arm(clock, stops=[(40, 0, 5)], start=np.array([10000, -5000, 8000, 2000, 3000, 1000]))
    q_goal = arm.joints_deg() + np.array([20.0, 10.0, -10.0, 5.0, -5.0, 10.0])
    assert seamtrack.move_to_start(arm, arm.model.fk(q_goal), "start of position (i)", quiet=True) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and LINE.match(err[0]), err
    assert np.max(np.abs(arm.joints_deg() - q_goal)) <= arm_mod.ARRIVAL_TOL_DEG
    arm2, fake2 = brain_arm(clock, stops=[(40, 0, 5)])
    with pytest.raises(RuntimeFailure, match=r"^arm1 failed command 1 \(faults"):
        seamtrack.move_to_start(arm2, arm2.model.fk(q_goal), "start", quiet=True, resume=False)


def test_a_signal_during_a_start_move_stops_it_and_the_run_says_interrupted(clock, monkeypatch):
    from droid.tasks import shell

    arm, fake = brain_arm(clock)
    monkeypatch.setattr(shell.Stop, "install", classmethod(lambda cls: None))
    monkeypatch.setattr(shell.Stop, "requested", False)
    step = fake.step

    def signal_mid_move():  # SIGINT arrives half a second into the move (Stop's handler)
        step()
        if fake.tick > 30:
            shell.Stop.requested = True
    fake.step = signal_mid_move
    job = SimpleNamespace(check_ready=lambda: None, go_to_start=lambda position: arm.move(
        "joint", GOAL, 2.0, interrupted=lambda: shell.Stop.requested))
    assert shell.ready_then_run(job, "i", "tracking", lambda: (0, "ran")) == (130, "interrupted before tracking")
    fake.step()
    assert fake.commands[-1][2] == L.STOP_TICKS and arm.stopped_cmd == fake.commands[-1][0]  # stopped there
    assert np.any(np.abs(fake.pos - GOAL) > 10000)


def test_no_resume_is_an_option_of_the_four_programs(capsys):
    from droid.tasks import move, seamtrack
    from droid.tasks.contact import prog

    assert seamtrack.build_parser().parse_args(["16", "--no-resume"]).no_resume
    assert not seamtrack.build_parser().parse_args(["16"]).no_resume
    assert prog.build_parser().parse_args(["arm1", "--no-resume"]).no_resume
    with pytest.raises(SystemExit):
        move.main(["--help"])
    assert "--no-resume" in capsys.readouterr().out


def test_the_contact_stop_on_an_arm_fault_names_the_fault():
    from droid.tasks.contact.core import STOP_ARM_FAULT, ArmStatus, ContactStation, FtStatus, Gains
    from droid.kinematics.transforms import trans

    st = ContactStation(Gains(), HZ, trans(0.0, 0.0, 250.0), force_n=20.0, speed_mm_s=10.0, length_mm=500.0)
    out = st.on_tick(0, ArmStatus(0, np.eye(4), L.FAULT_SERVO, False), FtStatus(np.zeros(3), True, False))
    assert out.stop == STOP_ARM_FAULT and st.detail == "fault bits 0x4: servo"
