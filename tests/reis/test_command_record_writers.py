"""The controller's Command record has one writer per field (docs/safety.md finding 11).

droid-agent copies the Brain's Command into the record on every heartbeat tick (the Brain's
joint target ``encoder_pos`` into ``encoder_cmd_ext``, its ``joint_time_count``, the pose, ...);
droid-planner writes its way-point and its own move's target and ticks left; droid-servo-agent
reads them all.  The three are separate processes, so any order of their writes happens on a
busy host.  Here the agent, the planner and the servo agent run on the same records in the
orders a live cell can give them: the planner late for a tick, and the agent's copy of a new
command falling between the planner's read and its write.
"""
import numpy as np

from droid.arm.planner import PlannerCore, PlannerStation
from droid.brain.db import arm_command
from droid.brain.db import layouts as L
from droid.brain.db.shmdb import MemoryDatabase
from droid.kinematics import load_robot
from droid.subunits.agent import AgentStation
from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis.servo_agent import ServoAgentCore

MODEL = load_robot("reis_v15")
P = 16_666_667  # heartbeat period [ns]
Q_START = np.array([10.0, 20.0, 10.0, 5.0, -60.0, 30.0])  # [deg]


class Cell:
    """The Reis's three programs on one arm's records (no servo: its report echoes the way-point)."""

    def __init__(self) -> None:
        self.brain = MemoryDatabase("command", L.ARM_COMMAND_LAYOUT)
        self.ctrl = MemoryDatabase("ctrl_command", L.CTRL_COMMAND_LAYOUT)
        self.status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
        self.agent = AgentStation(self.status, self.ctrl, P, 3)
        self.planner = PlannerStation(PlannerCore(MODEL), self.ctrl, self.status)
        self.servo_agent = ServoAgentCore()
        start = np.rint(MODEL.gearing.joints_to_counts(Q_START)).astype(np.int32)
        self.sent = start.astype(np.int64)
        self.status.update(homed=L.HOMED, encoder_pos=start, encoder_cmd=start)
        self.tick = 0

    def copy(self) -> None:
        """droid-agent: the Brain's Command of this tick copied in, the tick relayed."""
        self.tick += 1
        self.agent.on_command(self.brain.raw_bytes(), self.tick, self.tick * P)

    def serve(self) -> np.ndarray:
        """droid-servo-agent's period: the way-point it sends [counts]."""
        rep = sw.ServoReport(tick=self.tick * 8, mode=3, homed=True, homing_joint=-1, starved=False,
                             braking=False, fault=0, amps_on=True, encoder_pos=tuple(self.sent),
                             encoder_cmd=tuple(self.sent), following_error=(0,) * 6, dac=(0,) * 6)
        d = self.servo_agent.step(self.ctrl.read(), rep, True, ticked=True)
        assert d.message is not None, d.why
        self.sent = np.asarray(d.message.counts, np.int64)
        self.status.update(encoder_pos=self.sent.astype(np.int32), encoder_cmd=self.sent.astype(np.int32))
        return self.sent

    def tick_in_order(self) -> np.ndarray:
        self.copy()
        self.planner.cycle(self.tick)
        return self.serve()


def test_a_late_planner_is_bridged_at_its_velocity_not_sent_back_to_the_brains_last_joint_target():
    """The start move is a joint move (the Brain's ``encoder_pos`` = the start's counts); tracking
    then sends cartesian commands, which leave ``encoder_pos`` as it was.  When the planner is
    late for one tick, the servo agent bridges the period at the planner's velocity, bounded by
    the planner's move target.  It read that bound from ``encoder_cmd_ext``, which the agent had
    just overwritten with the Brain's stale start counts: every joint moving away from the start
    was sent back to it (the servo ramped at full speed, the following error grew past its
    limit: the README's main command, 2026-12-03)."""
    c = Cell()
    start = c.sent.copy()
    arm_command.joint(c.brain, start, 1)  # the start move: the arm is there
    for _ in range(3):
        c.tick_in_order()
    T = MODEL.fk(Q_START)
    steps = []
    for k in range(1, 30):  # away from the start along x at 1.5 mm a tick, a command every 2 ticks
        if k % 2 == 1:
            Tk = T.copy()
            Tk[0, 3] += 1.5 * (k + 1)
            arm_command.cart(c.brain, Tk, 2)
        before = c.sent.copy()
        steps.append(c.tick_in_order() - before)
    v = steps[-1]
    moved = c.sent - start
    assert np.count_nonzero(np.abs(moved) > 1000) >= 2, moved  # well away from the start counts
    before = c.sent.copy()
    c.copy()  # the second tick of the last command: the agent copies, the planner is late
    bridged = c.serve() - before
    assert np.all(np.abs(bridged - v) <= 2), (bridged, v)
    c.planner.cycle(c.tick)  # the planner's way-point of that tick: where the bridge went
    assert np.all(np.abs(np.asarray(c.ctrl.read()["encoder_cmd_int"]) - c.sent) <= 2)


def test_a_new_joint_command_copied_in_while_the_planner_plans_is_taken_as_the_brain_wrote_it():
    """A planner late for tick n reads the record, is preempted, and meanwhile the agent copies
    tick n+1's Command -- a new joint command; the planner writes tick n's plan and at once runs
    tick n+1's cycle (its tick was queued).  Its write must not overwrite what the agent copied
    (the Brain's target and ticks): tick n+1 takes the new command as the Brain wrote it, not with
    the old move's target and ticks left (which would end it at once where it stands)."""
    c = Cell()
    start = c.sent.copy()
    arm_command.joint(c.brain, start, 1)
    for _ in range(3):
        c.tick_in_order()
    goal = start + np.array([3000, -2000, 1500, 800, -900, 1200])
    step = c.planner.core.step

    def step_then_new_command(cmd, st):  # preempted between its read and its write
        out = step(cmd, st)
        arm_command.joint(c.brain, goal, 60)
        c.copy()  # tick n+1's copy
        return out

    c.planner.core.step = step_then_new_command
    c.copy()
    c.planner.cycle(c.tick)  # tick n, late
    c.planner.core.step = step
    c.planner.cycle(c.tick)  # tick n+1 at once, before any other copy
    first = c.serve() - start
    assert np.all(np.abs(first - (goal - start) / 60) <= 2), first  # the Brain's target in its 60 ticks
    ways = [c.tick_in_order() for _ in range(70)]
    assert np.array_equal(ways[-1], goal), (ways[-1], goal)
