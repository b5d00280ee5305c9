"""The planner core (thesis §4.1.7): plan_joint_cmd, the pick, refusal, cancel on a lost stream."""
import numpy as np
import pytest

from droid.brain.db import layouts as L
from droid.kinematics import load_robot
from droid.arm.planner import PlannerCore

MODEL = load_robot("reis_v15")


def records(homed=True, pos=(0,) * 6):
    cmd = L.new_record(L.CTRL_COMMAND_LAYOUT)
    cmd["link_alive"] = 1
    cmd["cmd_mode"] = L.NORMAL_MODE
    st = L.new_record(L.CTRL_STATUS_LAYOUT)
    st["homed"] = int(homed)
    st["encoder_pos"] = pos
    return cmd, st


def joint_cmd(cmd, counts, ticks, cmd_id):
    cmd["coord"], cmd["cmd_mode"] = L.JSPACE, L.NORMAL_MODE
    cmd["encoder_cmd_ext"], cmd["joint_time_count"], cmd["cmd_id"] = counts, ticks, cmd_id


def test_nothing_before_homing():
    core = PlannerCore(MODEL)
    cmd, st = records(homed=False)
    joint_cmd(cmd, [1000] * 6, 10, 1)
    out = core.step(cmd, st)
    assert out.encoder_cmd_int is None and out.busy is None


def test_holds_where_it_is_after_homing_and_interpolates_linearly():
    core = PlannerCore(MODEL)
    pos = (100, -200, 300, 0, 50, -60)
    cmd, st = records(pos=pos)
    out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == list(pos) and out.busy == 0
    target = np.array([1100, 800, -700, 0, 50, 940])
    joint_cmd(cmd, target, 10, 7)
    way = []
    for _ in range(12):
        out = core.step(cmd, st)
        way.append(out.encoder_cmd_int.astype(float))
    assert way[9].tolist() == target.tolist()  # on target after joint_time_count ticks
    assert way[11].tolist() == target.tolist()
    steps = np.diff(np.array([pos] + way[:10]), axis=0)
    assert np.allclose(steps, (target - pos) / 10, atol=1)  # equal steps: a linear joint move
    assert out.busy == 0


def test_cartesian_command_uses_the_pick():
    core = PlannerCore(MODEL)
    cmd, st = records()
    core.step(cmd, st)
    q_goal = np.array([20.0, 10.0, 15.0, 5.0, 30.0, -10.0])
    T = MODEL.fk(q_goal)
    cmd["coord"], cmd["cmd_mode"], cmd["cmd_id"], cmd["cart_time_count"] = L.CARTSPACE, L.NORMAL_MODE, 3, 5
    cmd["x"], cmd["y"], cmd["z"], cmd["R"] = T[0, 3], T[1, 3], T[2, 3], T[:3, :3]
    for _ in range(6):
        out = core.step(cmd, st)
    q = MODEL.gearing.counts_to_joints(out.encoder_cmd_int.astype(float))
    assert np.allclose(q, q_goal, atol=0.01)  # the nearest solution from home, within a count


def test_unreachable_and_out_of_limit_targets_are_refused_without_motion():
    core = PlannerCore(MODEL)
    pos = (10,) * 6
    cmd, st = records(pos=pos)
    core.step(cmd, st)
    joint_cmd(cmd, [10**8] * 6, 5, 2)
    out = core.step(cmd, st)
    assert out.cmd_result == L.CMD_REFUSED and out.cmd_id == 2
    assert list(out.encoder_cmd_int) == list(pos)
    cmd["coord"], cmd["cmd_id"], cmd["cart_time_count"] = L.CARTSPACE, 3, 5
    cmd["x"], cmd["y"], cmd["z"], cmd["R"] = 5000.0, 0.0, 0.0, np.eye(3)
    out = core.step(cmd, st)
    assert out.cmd_result == L.CMD_REFUSED and list(out.encoder_cmd_int) == list(pos)


@pytest.mark.parametrize("how, cause", [("link", "Brain link lost"), ("braking", "faults: braking"),
                                        ("servo", "faults: servo")])
def test_lost_stream_cancels_and_holds_until_a_new_command(how, cause):
    core = PlannerCore(MODEL)
    cmd, st = records()
    core.step(cmd, st)
    joint_cmd(cmd, [5000] * 6, 60, 4)
    for _ in range(10):
        core.step(cmd, st)
    st["encoder_pos"] = [700] * 6  # where the arm stopped
    if how == "link":
        cmd["link_alive"] = 0
    else:
        st["fault"] = L.FAULT_BRAKING if how == "braking" else L.FAULT_SERVO
    out = core.step(cmd, st)
    assert out.cmd_result == L.CMD_FAILED and out.cmd_id == 4
    assert out.note == f"cancelled command 4: {cause}"  # the log line names the cause (issue 16)
    assert list(out.encoder_cmd_int) == [700] * 6 and out.busy == 0
    cmd["link_alive"], st["fault"] = 1, 0
    for _ in range(5):  # the old command is not resumed
        out = core.step(cmd, st)
        assert list(out.encoder_cmd_int) == [700] * 6
    joint_cmd(cmd, [800] * 6, 2, 5)
    core.step(cmd, st)
    out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == [800] * 6


def test_follows_the_arm_outside_normal_mode():
    core = PlannerCore(MODEL)
    cmd, st = records(pos=(0,) * 6)
    core.step(cmd, st)
    cmd["cmd_mode"] = L.JOG_MODE  # droid-jog moves the arm through the servo agent
    st["encoder_pos"] = (500, -400, 300, 0, 0, 7)
    out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == [500, -400, 300, 0, 0, 7]
    joint_cmd(cmd, [600, -400, 300, 0, 0, 7], 2, 9)  # back to NORMAL: starts from there
    out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == [550, -400, 300, 0, 0, 7]


def test_commands_fail_while_the_servo_is_down():
    core = PlannerCore(MODEL)
    cmd, st = records()
    core.step(cmd, st)
    st["fault"] = L.FAULT_WATCHDOG
    joint_cmd(cmd, [900] * 6, 5, 3)
    out = core.step(cmd, st)
    assert out.cmd_result == L.CMD_FAILED and out.cmd_id == 3
    assert list(out.encoder_cmd_int) == [0] * 6 and out.busy == 0


def test_servo_agent_never_sends_a_stale_far_way_point():
    """A way-point more than two command periods of travel from the servo's target is
    stale (e.g. the planner kept interpolating while the servo agent was stalled): the
    agent sends nothing and flags BRAKING so the planner re-anchors."""
    from droid.subunits.reis import servo_wire as sw
    from droid.subunits.reis.servo_agent import ServoAgentCore

    agent = ServoAgentCore()
    cmd = L.new_record(L.CTRL_COMMAND_LAYOUT)
    cmd["link_alive"], cmd["cmd_mode"], cmd["brain_tick"], cmd["planner_tick"] = 1, L.NORMAL_MODE, 100, 100
    rep = sw.ServoReport(tick=1, mode=3, homed=True, homing_joint=-1, starved=False, braking=False, fault=0,
                         amps_on=True, encoder_pos=(1000,) * 6, encoder_cmd=(1000,) * 6,
                         following_error=(0,) * 6, dac=(0,) * 6)
    cmd["encoder_cmd_int"] = [1100] * 6  # a normal next way-point
    d = agent.step(cmd, rep, True)
    assert d.message is not None and d.message.counts == (1100,) * 6
    cmd["encoder_cmd_int"] = [9000, 1000, 1000, 1000, 1000, 1000]  # 8000 counts ahead: stale
    cmd["brain_tick"], cmd["planner_tick"] = 101, 101  # the planner's next tick
    d = agent.step(cmd, rep, True)
    assert d.message is None and d.fault_bits & L.FAULT_BRAKING


def test_a_stop_command_ends_the_move_where_its_way_point_is_and_holds():
    """Issue 16: a task that gives up writes a stop (0 ticks); the move is not carried on."""
    core = PlannerCore(MODEL)
    cmd, st = records()
    core.step(cmd, st)
    joint_cmd(cmd, [6000] * 6, 60, 1)
    for _ in range(20):
        out = core.step(cmd, st)
    where = out.encoder_cmd_int.copy()
    assert 1500 < where[0] < 2500 and out.busy > 0  # a third of the way
    joint_cmd(cmd, [6000] * 6, L.STOP_TICKS, 2)  # the stop (its target is ignored)
    out = core.step(cmd, st)
    assert out.cmd_id == 2 and out.cmd_result == L.CMD_OK and out.busy == 0
    assert "stopped by command 2" in out.note
    for _ in range(60):
        out = core.step(cmd, st)
        assert np.array_equal(out.encoder_cmd_int, where)  # held, never resumed
    assert out.busy == 0
    joint_cmd(cmd, [0] * 6, 30, 3)  # and a new move works
    for _ in range(31):
        out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == [0] * 6


def _moving_agent(v_counts_per_period: float, ext: int):
    """A servo agent that sent way-points 0, v, 2v (planner ticks 1..3) toward ``ext``."""
    from droid.subunits.reis import servo_wire as sw
    from droid.subunits.reis.servo_agent import ServoAgentCore

    agent = ServoAgentCore()
    cmd = L.new_record(L.CTRL_COMMAND_LAYOUT)
    cmd["link_alive"], cmd["cmd_mode"] = 1, L.NORMAL_MODE
    cmd["plan_ext"] = [ext] * 6  # the planner's move target
    sent = []
    for k in range(3):
        cmd["brain_tick"] = cmd["planner_tick"] = k + 1
        cmd["encoder_cmd_int"] = [int(k * v_counts_per_period)] * 6
        rep = sw.ServoReport(tick=k, mode=3, homed=True, homing_joint=-1, starved=False, braking=False, fault=0,
                             amps_on=True, encoder_pos=cmd["encoder_cmd_int"], encoder_cmd=cmd["encoder_cmd_int"],
                             following_error=(0,) * 6, dac=(0,) * 6)
        sent.append(agent.step(cmd, rep, True).message.counts[0])
    return agent, cmd, rep, sent


def test_way_points_that_stop_coming_end_in_the_braking_profile_not_at_once():
    """Issue 16 (docs/safety.md finding 1): when the planner's way-points stop (the Brain link
    went silent), the agent does not re-send the last one -- the servo would stop within one
    period at any deceleration -- but decelerates at the servo's braking profile, then holds;
    once the link is declared lost and the arm is at rest it falls silent."""
    agent, cmd, rep, sent = _moving_agent(600.0, ext=100_000)
    assert sent == [0, 600, 1200]
    out = []
    for _ in range(30):  # no tick and planner_tick frozen: no new way-point
        d = agent.step(cmd, rep, True, ticked=False)
        out.append(d.message.counts[0])
    steps = np.diff([1200] + out)
    assert steps[0] < 600 and np.all(steps >= 0) and np.all(np.diff(steps) <= 0)  # slowing, never back
    decel = agent.brake_per_period[0]
    assert np.all(np.abs(np.diff(np.concatenate([[600], steps]))) <= decel + 2)  # the profile's rate (rounded counts)
    assert steps[-1] == 0 and out[-1] == out[-2]  # at rest, held
    cmd["link_alive"] = 0
    assert agent.step(cmd, rep, True).message is None  # at rest: silent (the servo holds)


def test_a_late_planner_is_bridged_by_one_period_of_its_own_velocity():
    """The tick came but the planner has not written its way-point yet: one period at the
    planner's velocity (the next way-point lands where the arm is), then -- still nothing --
    the braking profile."""
    agent, cmd, rep, sent = _moving_agent(600.0, ext=100_000)
    d = agent.step(cmd, rep, True, ticked=True)
    assert d.message.counts[0] == 1800
    cmd["brain_tick"] += 1  # caught up: two planner ticks at once
    cmd["planner_tick"] += 2
    cmd["encoder_cmd_int"] = [2400] * 6
    assert agent.step(cmd, rep, True).message.counts[0] == 2400  # on the planner's path again
    cmd["brain_tick"] += 1  # late again, twice in a row: bridge once, then brake
    steps = [agent.step(cmd, rep, True, ticked=True).message.counts[0] for _ in range(2)]
    assert steps[0] == 3000 and 3000 < steps[1] < 3600


def test_after_braking_the_arm_waits_for_the_planner_instead_of_backing_up():
    """The ticks come back after two braking periods: the arm is ahead of the planner's
    way-points, so a joint the planner still drives the same way holds until they pass it."""
    agent, cmd, rep, sent = _moving_agent(600.0, ext=100_000)
    braked = [agent.step(cmd, rep, True, ticked=False).message.counts[0] for _ in range(2)]
    assert 1200 + 600 + 600 > braked[1] > 1200 + 600  # two slowing periods: ~1200 + 555 + 510
    out = []
    for k in range(1, 6):  # the planner resumes at 600 counts a tick from 1200
        cmd["brain_tick"] += 1
        cmd["planner_tick"] += 1
        cmd["encoder_cmd_int"] = [1200 + 600 * k] * 6
        out.append(agent.step(cmd, rep, True).message.counts[0])
    assert out[0] == braked[1]  # held, not backed up to 1800
    assert all(b >= a for a, b in zip([braked[1]] + out, out))  # never backwards
    assert out[-1] == 1200 + 600 * 5  # back on the planner's way-points once they passed


def test_braking_after_silent_way_points_never_passes_the_moves_target():
    agent, cmd, rep, sent = _moving_agent(600.0, ext=1500)
    cmd["link_alive"] = 0  # the link is declared lost at once
    out = [agent.step(cmd, rep, True).message for _ in range(3)]
    assert out[0].counts[0] == 1500  # 1200 + 600 less the profile would pass 1500: stops on it
    assert out[1] is None  # at rest on the target: silent


def test_servo_agent_refuses_a_heartbeat_that_is_not_its_command_rate(tmp_path, cell_name):
    """The servo takes one way-point per 60 Hz period and droid-servo-agent cycles on the
    relayed tick: a cell at another heartbeat is refused before anything opens."""
    import re

    from tests.brain.cellutil import droid, make_cell_file

    path = make_cell_file(tmp_path, cell_name)
    path.write_text(re.sub(r"(?m)^heartbeat_hz = .*$", "heartbeat_hz = 30.0", path.read_text()))
    out = droid("droid.subunits.reis.servo_agent", "arm1", "--cell", str(path))
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "heartbeat_hz is 30" in lines[0] and "Traceback" not in out.stderr
