"""The ft6 Command (bias, the over-force guard) from the Brain to droid-ft, and the arm's
planner on FAULT_FORCE (issue 27: the over-force stop beside the arm; thesis §7.3)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from droid.brain.db import layouts as L
from droid.brain.cell.cellfile import load_cell
from droid.brain.cell.registry import classes
from droid.brain.db.shmdb import MemoryDatabase
from droid.cli import BadInput
from droid.kinematics import load_robot
from droid.observe.scene import is_arm
from droid.subunits.agent import AgentStation, CommandCopier
from droid.subunits.ft.prog import FtCommandRule, FtCore, FtStation, ft_options
from droid.subunits.ft import rdt
from droid.arm.planner import PlannerCore
from droid.tasks.ft_sensor import BrainFt
from tests.ft.test_ft import CAL, ScriptedDevice, rec, settle
from droid.sim.ft.netft import CalibrationPage


def ft_command(**fields) -> bytes:
    r = L.new_record(L.FT6_COMMAND_LAYOUT)
    for k, v in fields.items():
        r[k] = v
    return r.tobytes()


def test_ft6_has_a_command_that_the_agent_copies_with_its_link_fields():
    c = classes()["ft6"]
    assert c.brain["command"] is L.FT6_COMMAND_LAYOUT and c.local["ctrl_command"] is L.FT6_CTRL_COMMAND_LAYOUT
    assert not c.kinematic and not is_arm({"class": "ft6", "areas": {"status": 1, "command": 1}})
    assert is_arm({"class": "arm6r", "areas": {"status": 1, "command": 1}})
    ctrl = MemoryDatabase("ft.ctrl_command", L.FT6_CTRL_COMMAND_LAYOUT)
    status = MemoryDatabase("ft.ctrl_status", L.FT6_STATUS_LAYOUT)
    station = AgentStation(status, ctrl, 16_666_667, 3, CommandCopier(ctrl, c.brain["command"], c.command_map))
    station.on_command(ft_command(guard_force_n=40.0, bias_id=3, sent=1, cmd_id=7), 12, 0)
    got = ctrl.read()
    assert (float(got["guard_force_n"]), int(got["bias_id"]), int(got["cmd_id"])) == (40.0, 3, 7)
    assert int(got["brain_tick"]) == 12 and int(got["link_alive"]) == 1
    with pytest.raises(L.LayoutError):  # an arm's Command is not an ft6 one: nothing copied
        station.on_command(L.new_record(L.ARM_COMMAND_LAYOUT).tobytes(), 13, 1)
    assert int(ctrl.read()["brain_tick"]) == 12


def test_the_rule_biases_on_a_new_bias_id_only_and_the_guard_trips_above_its_limit_or_blind():
    rule = FtCommandRule()
    cmd = L.new_record(L.FT6_CTRL_COMMAND_LAYOUT)
    cmd["bias_id"] = 5
    assert rule.take(cmd) is False  # the value present at start is not replayed
    assert rule.take(cmd) is False
    cmd["bias_id"] = 6
    assert rule.take(cmd) is True and rule.take(cmd) is False and rule.biases == 1
    fields = {"valid": 1, "force_N": np.array([30.0, 0.0, 40.0])}  # |F| = 50 N
    assert not rule.over(fields)  # disarmed
    for bad in (float("nan"), float("inf"), -5.0):
        cmd["guard_force_n"] = bad
        rule.take(cmd)
        assert rule.limit_n == 0.0 and not rule.over(fields)
    cmd["guard_force_n"] = 60.0
    rule.take(cmd)
    assert not rule.over(fields)
    cmd["guard_force_n"] = 45.0
    rule.take(cmd)
    assert rule.over(fields)
    rule.take(cmd)
    assert rule.over({"valid": 1, "force_N": np.zeros(3)})  # latched: a dip below does not open it
    cmd["guard_force_n"] = 0.0
    rule.take(cmd)
    assert not rule.over(fields)  # disarmed: open
    cmd["guard_force_n"] = 45.0
    rule.take(cmd)
    assert not rule.over({"valid": 1, "force_N": np.zeros(3)})  # re-armed, below the limit
    assert rule.over({"valid": 0, "force_N": np.zeros(3)})  # armed and blind: trips


def test_a_bias_command_reaches_the_device_once_records_flow():
    dev = ScriptedDevice()
    page = CalibrationPage("127.0.0.1", 0, CAL.xml())
    drv = rdt.open_ft(f"netft://127.0.0.1:{dev.port}?http_port={page.port}")
    cmd = L.new_record(L.FT6_CTRL_COMMAND_LAYOUT)
    try:
        station = FtStation(drv, FtCore(np.eye(4), 10**9), 10**9, log=lambda line: None)
        station.step(0, cmd)
        assert dev.request()[1] == rdt.CMD_START_REALTIME
        dev.send(rec(1))
        f = settle(station, 1, lambda f: f["records"] == 1)
        assert f["biased"] == 0  # no bias asked yet
        cmd["bias_id"] = 1
        dev.send(rec(2))
        for _ in range(200):  # datagrams on loopback arrive within microseconds (bounded)
            f = station.step(2, cmd)
            if f["records"] == 2:
                break
            time.sleep(0.005)
        assert f["biased"] == 1 and dev.request()[1] == rdt.CMD_SET_BIAS and station.rule.biases == 1
    finally:
        drv.close()
        page.close()
        dev.close()


def test_guard_arm_must_be_an_arm_on_the_sensors_host(tmp_path):
    from droid.brain.cell.cellfile import builtin_cell_path

    text = builtin_cell_path().read_text()
    line = 'guard_arm = "arm1"'
    assert text.count(line) == 1  # the shipped cell guards arm1
    cell = load_cell(builtin_cell_path())
    assert ft_options(cell.subunit("ft"), cell).guard_arm == "arm1"
    for arm, why in (("nosuch", "must name an arm subunit"), ("mvs", "not an arm"), ("gmf1", "runs on host")):
        bad = tmp_path / f"{arm}.toml"
        bad.write_text(text.replace(line, f'guard_arm = "{arm}"'))
        c = load_cell(bad)
        with pytest.raises(BadInput, match=why):
            ft_options(c.subunit("ft"), c)
    # an arm on the same host whose programs do not act on FAULT_FORCE: a guard nobody obeys
    reis = '"droid-reis-agent", "droid-planner"]'
    assert text.count(reis) == 1
    bad = tmp_path / "noplanner.toml"
    bad.write_text(text.replace(reis, '"droid-reis-agent"]'))
    c = load_cell(bad)
    with pytest.raises(BadInput, match="runs no droid-planner"):
        ft_options(c.subunit("ft"), c)


def test_brain_ft_writes_one_command_per_request_and_sees_it_delivered(tmp_path):
    from droid.brain.cell.cellfile import builtin_cell_path

    cell = load_cell(builtin_cell_path())
    ft = BrainFt(cell, "ft")
    ft.command = MemoryDatabase("ft.command", L.FT6_COMMAND_LAYOUT)
    a = ft.write(bias=True, guard_force_n=40)
    r = ft.command.read()
    assert (int(r["bias_id"]), float(r["guard_force_n"]), int(r["cmd_id"]), int(r["sent"])) == (1, 40.0, a, 1)
    assert not ft.delivered(a)
    b = ft.write(guard_force_n=0)  # disarm; the bias is not asked again
    r = ft.command.read()
    assert b == a + 1 and int(r["bias_id"]) == 1 and float(r["guard_force_n"]) == 0.0
    assert ft.delivered(a)  # replaced by a later one
    ft.command.update(sent=0)
    assert ft.delivered(b)
    with pytest.raises(BadInput, match="guard_force_n"):
        ft.write(guard_force_n=float("nan"))
    with pytest.raises(BadInput, match="not an ft6"):
        BrainFt(cell, "arm1")


def test_the_planner_cancels_on_force_refuses_new_moves_and_takes_them_once_clear():
    core = PlannerCore(load_robot("reis_v15"))
    cmd = L.new_record(L.CTRL_COMMAND_LAYOUT)
    cmd["link_alive"], cmd["cmd_mode"] = 1, L.NORMAL_MODE
    st = L.new_record(L.CTRL_STATUS_LAYOUT)
    st["homed"] = 1
    core.step(cmd, st)

    def joint(counts, ticks, cmd_id):
        cmd["coord"], cmd["cmd_mode"] = L.JSPACE, L.NORMAL_MODE
        cmd["encoder_cmd_ext"], cmd["joint_time_count"], cmd["cmd_id"] = counts, ticks, cmd_id

    joint([5000] * 6, 60, 4)
    for _ in range(10):
        wp = list(core.step(cmd, st).encoder_cmd_int)
    st["encoder_pos"] = [700] * 6  # behind the way-point: a pressing arm's following error
    st["fault"] = L.FAULT_FORCE
    out = core.step(cmd, st)
    assert out.cmd_result == L.CMD_FAILED and out.note == "cancelled command 4: faults: force"
    assert list(out.encoder_cmd_int) == wp and out.busy == 0  # holds its way-point: no step back
    joint([9000] * 6, 30, 5)  # a new move while the guard holds: refused, nothing moves
    out = core.step(cmd, st)
    assert out.cmd_result == L.CMD_REFUSED and out.cmd_id == 5 and "over-force" in out.note
    assert list(out.encoder_cmd_int) == wp
    st["fault"] = L.FAULT_FORCE | L.FAULT_BRAKING  # and the servo braked: re-anchored where it is
    out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == [700] * 6
    st["fault"] = 0  # the task disarmed the guard
    out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == [700] * 6  # the refused move is not taken up later
    joint([800] * 6, 2, 6)
    core.step(cmd, st)
    out = core.step(cmd, st)
    assert list(out.encoder_cmd_int) == [800] * 6
