"""droid-egm and the controller twin in one loop, virtual time (issue 26): the ABB subunit's chain
as a cell runs it -- the Reis's planner unchanged (PlannerCore/PlannerStation), droid-egm's
station (EgmCore + the record writes) on the relayed tick, the twin stepped at the world's
1 kHz -- with the EGM datagrams carried in memory (what the sockets would carry, byte for
byte) and the databases in process memory (MemoryDatabase)."""
from __future__ import annotations

import numpy as np
import pytest

from droid.brain.db.layouts import (CTRL_COMMAND_LAYOUT, CTRL_STATUS_LAYOUT, FAULT_DEVICE, FAULT_SERVO, HOMED, JSPACE,
                                 NORMAL_MODE, CMD_OK)
from droid.brain.db.shmdb import MemoryDatabase
from droid.kinematics import load_robot
from droid.sim.abb.controller import EgmController, EgmTwinParams
from droid.subunits.abb.egm_core import EgmCore
from droid.subunits.abb.egm_layout import EGM_STATUS_LAYOUT
from droid.subunits.abb.egm_prog import EgmStation
from droid.arm.planner import PlannerCore, PlannerStation

MODEL = load_robot("abb_irb2400")
START = [0.0, 10.0, 10.0, 0.0, 60.0, 0.0]
HB_HZ = 60.0
CONTROLLER = ("127.0.0.1", 40123)


class Loop:
    """World at 1 ms, heartbeat at 60 Hz (integer ns), datagrams handed over within the step."""

    def __init__(self, stale_ticks: int = 12, **twin) -> None:
        self.twin = EgmController(MODEL, EgmTwinParams(**twin), START)
        self.cmd = MemoryDatabase("ctrl_command", CTRL_COMMAND_LAYOUT)
        self.status = MemoryDatabase("ctrl_status", CTRL_STATUS_LAYOUT)
        self.egm = MemoryDatabase("egm", EGM_STATUS_LAYOUT)
        self.cmd.update(cmd_mode=NORMAL_MODE, coord=JSPACE, link_alive=1)
        self.station = EgmStation(EgmCore(MODEL, stale_ticks, HB_HZ), self.cmd, self.status, self.egm)
        self.planner = PlannerStation(PlannerCore(MODEL), self.cmd, self.status)
        self.t_ns = 0
        self.tick = 0
        self.drop_robot = False  # the controller's datagrams lost on the way
        self.mute_sensor = False  # droid-egm's replies lost on the way

    def run(self, seconds: float) -> None:
        period = int(round(1e9 / HB_HZ))
        for _ in range(int(round(seconds * 1000))):
            self.t_ns += 1_000_000
            for data in self.twin.advance(self.t_ns / 1e9):
                if self.drop_robot:
                    continue
                reply = self.station.take(data, CONTROLLER, self.t_ns)
                if reply is not None and not self.mute_sensor:
                    assert reply[1] == CONTROLLER
                    self.twin.receive(reply[0], self.t_ns / 1e9)
            if self.t_ns >= (self.tick + 1) * period:  # the relayed tick: agent, planner, droid-egm
                self.tick += 1
                self.cmd.update(brain_tick=self.tick)
                self.planner.cycle(self.tick)
                self.station.cycle(self.t_ns)

    def command_joints(self, q_deg, ticks: int) -> int:
        cmd_id = int(self.cmd.read()["cmd_id"]) + 1
        counts = np.rint(MODEL.gearing.joints_to_counts(np.asarray(q_deg, float))).astype(np.int32)
        self.cmd.update(encoder_cmd_ext=counts, joint_time_count=ticks, coord=JSPACE, cmd_mode=NORMAL_MODE,
                        cmd_id=cmd_id, sent=1)
        return cmd_id


def test_a_joint_command_reaches_the_twin_and_the_feedback_returns():
    loop = Loop()
    loop.run(0.2)
    st = loop.status.read()
    assert int(st["homed"]) == HOMED and int(st["fault"]) == 0
    assert np.allclose(MODEL.gearing.counts_to_joints(st["encoder_pos"].astype(float)), loop.twin.q_motor_deg, atol=0.002)
    assert np.allclose(loop.twin.q_motor_deg, START, atol=0.05)  # the twin settles under gravity at power-up
    target = np.array([20.0, 25.0, -10.0, 30.0, 45.0, -60.0])
    cmd_id = loop.command_joints(target, 120)  # 2 s: the slowest joint at 30 deg/s
    loop.run(1.0)
    st = loop.status.read()
    assert int(st["cmd_id"]) == cmd_id and int(st["cmd_result"]) == CMD_OK and int(st["busy"]) > 0
    loop.run(1.6)
    st = loop.status.read()
    assert int(st["busy"]) == 0 and int(st["fault"]) == 0
    assert np.max(np.abs(loop.twin.q_motor_deg - target)) < 0.01  # the twin's resolvers
    fed_back = MODEL.gearing.counts_to_joints(st["encoder_pos"].astype(float))
    assert np.max(np.abs(fed_back - target)) < 0.01  # ... and the Status record (Table 4.2)
    egm = loop.egm.read()
    assert np.max(np.abs(egm["feedback_deg"] - target)) < 0.01
    assert np.allclose(egm["target_deg"], target, atol=0.002)
    assert int(egm["convergence"]) == 1 and int(egm["lost"]) == 0 and int(egm["malformed"]) == 0
    k = loop.station.core.counters  # (the record holds them as of the last heartbeat cycle)
    assert k.accepted == k.replies == loop.twin.received > 0 and 0 < int(egm["replies"]) <= k.replies
    assert loop.twin.bad == 0 and loop.twin.timeouts == 0


def test_feedback_lost_sets_the_link_fault_and_the_twin_stops_on_its_timeout():
    loop = Loop(comm_timeout_s=0.1)
    loop.run(0.2)
    loop.command_joints([60.0, 10.0, 10.0, 0.0, 60.0, 0.0], 60)
    loop.run(0.4)
    assert 5.0 < loop.twin.q_deg[0] < 55.0  # on its way
    loop.drop_robot = True  # the network drops the controller's datagrams: droid-egm hears nothing
    loop.run(0.3)
    st = loop.status.read()
    assert int(st["fault"]) & FAULT_DEVICE and int(st["homed"]) == 0
    assert loop.twin.timeouts == 1 and not loop.twin.guiding  # nothing answered it for 100 ms
    q_stop = loop.twin.q_deg.copy()
    loop.run(0.5)
    assert np.max(np.abs(loop.twin.q_deg - q_stop)) < 0.05
    assert q_stop[0] < 59.0  # stopped short of the target
    # the link comes back: homed again, no fault, and the arm stays where it stopped until a command
    loop.drop_robot = False
    loop.run(1.0)
    st = loop.status.read()
    assert int(st["homed"]) == HOMED and int(st["fault"]) & FAULT_DEVICE == 0
    assert np.max(np.abs(loop.twin.q_deg - q_stop)) < 0.05


def test_motors_off_is_a_servo_fault_and_nothing_jumps_when_they_return():
    loop = Loop()
    loop.run(0.2)
    loop.twin.set_motors(False)
    loop.run(0.1)
    assert int(loop.status.read()["fault"]) & FAULT_SERVO
    cmd_id = loop.command_joints([30.0, 10.0, 10.0, 0.0, 60.0, 0.0], 60)
    loop.run(0.3)
    st = loop.status.read()
    assert int(st["cmd_id"]) == cmd_id and int(st["cmd_result"]) != CMD_OK  # failed: cannot move
    loop.twin.set_motors(True)
    loop.run(0.5)
    assert int(loop.status.read()["fault"]) == 0
    assert np.allclose(loop.twin.q_deg, START, atol=0.01)


@pytest.mark.parametrize("stale_ticks", [3, 12])
def test_stale_rule_follows_the_cells_stale_ticks(stale_ticks):
    loop = Loop(stale_ticks=stale_ticks)
    loop.run(0.2)
    loop.drop_robot = True
    period_s = 1.0 / HB_HZ
    loop.run((stale_ticks - 1.5) * period_s)
    assert not int(loop.status.read()["fault"]) & FAULT_DEVICE
    loop.run(2.0 * period_s)
    assert int(loop.status.read()["fault"]) & FAULT_DEVICE
