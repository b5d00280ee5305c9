"""The ABB subunit in lockstep (droid.sim.abb.lockstep.LockstepAbbArm), built from cells/abb_weld.toml:
droid-reis-agent, droid-planner and droid-egm's stations with the abb_egm controller twin, the EGM
datagrams carried in memory as bytes.  Virtual time only: nothing binds a socket."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.db.layouts import CMD_OK, HOMED
from droid.cli import BadInput
from droid.sim.abb.lockstep import LockstepAbbArm
from droid.sim.lockstep import Scheduler

CELL = Path(__file__).resolve().parents[2] / "droid" / "cells" / "abb_weld.toml"
START_DEG = np.array([0.0, 10.0, 10.0, 0.0, 60.0, 0.0])  # the cell's abb device's start_deg
TARGET_DEG = np.array([20.0, 25.0, -10.0, 30.0, 45.0, -60.0])
#: a joint move's end: the controller's resolvers (motor side) within this of the target [deg]
JOINT_TOL_DEG = 0.01
#: a cartesian move's end: the Status pose (FK of the feedback) within this of the target [mm]
CART_TOL_MM = 0.05
#: ... and the true flange (the links, after the reducers' deflection) within this [mm]
TRUE_TOL_MM = 0.5


def arm_on(cell_path=CELL) -> LockstepAbbArm:
    return LockstepAbbArm(Scheduler(60.0), load_cell(cell_path), "abb")


def counts(arm, q_deg) -> np.ndarray:
    return np.rint(arm.model.gearing.joints_to_counts(np.asarray(q_deg, float))).astype(np.int32)


def status_pose(arm) -> np.ndarray:
    st = arm.status
    T = np.eye(4)
    T[:3, :3] = st["R"]
    T[:3, 3] = (float(st["x"]), float(st["y"]), float(st["z"]))
    return T


def test_homes_at_once_then_a_joint_and_a_cart_move_end_on_target_with_no_datagram_dropped():
    arm = arm_on()
    assert arm.home(0.5)  # absolute measurement: acknowledged once the feedback flows
    assert int(arm.status["homed"]) == HOMED and int(arm.status["fault"]) == 0
    assert np.allclose(arm.controller.q_motor_deg, START_DEG, atol=0.05)
    # commanded in the very tick after the home, as FullArm.prepare does (EgmCore's re-anchoring)
    cmd = arm.command_joint(counts(arm, TARGET_DEG), arm.ticks_for(2.0))
    assert arm.move_done(cmd, 3.0)
    assert int(arm.status["cmd_result"]) == CMD_OK
    arm.sched.run_for(0.5)
    assert np.max(np.abs(arm.controller.q_motor_deg - TARGET_DEG)) < JOINT_TOL_DEG
    fed_back = arm.model.gearing.counts_to_joints(arm.status["encoder_pos"].astype(float))
    assert np.max(np.abs(fed_back - TARGET_DEG)) < JOINT_TOL_DEG  # the Brain's Status (Table 3.1)
    T = arm.model.fk(TARGET_DEG + [-10.0, 5.0, 5.0, -20.0, 10.0, 30.0])
    cmd = arm.command_cart(T, arm.ticks_for(2.0))
    assert arm.move_done(cmd, 3.0) and int(arm.status["cmd_result"]) == CMD_OK
    arm.sched.run_for(0.5)
    assert np.linalg.norm(status_pose(arm)[:3, 3] - T[:3, 3]) < CART_TOL_MM
    assert np.allclose(status_pose(arm)[:3, :3], T[:3, :3], atol=1e-4)
    assert np.linalg.norm(arm.wcp_global()[:3, 3] - T[:3, 3]) < TRUE_TOL_MM
    k = arm.counters
    assert k.accepted == k.replies == arm.controller.received > 1000  # 250 Hz for 5.5 s
    assert k.lost == k.dropped == k.reconnects == 0
    assert arm.controller.bad == 0 and arm.controller.timeouts == 0
    egm = arm.egm_db.read()
    assert int(egm["lost"]) == 0 and int(egm["convergence"]) == 1
    assert arm.truth()["arm"] == "abb"


def test_the_same_run_twice_gives_the_same_records():
    def run() -> bytes:
        arm = arm_on()
        arm.home(0.5)
        arm.command_joint(counts(arm, TARGET_DEG), arm.ticks_for(1.0))
        arm.sched.run_for(1.3)
        return arm.brain_status.raw_bytes() + arm.ctrl_status.raw_bytes() + arm.controller.q_deg.tobytes()

    assert run() == run()


def test_droid_egm_stopped_the_twin_times_out_then_guides_again_when_it_answers():
    arm = arm_on()
    arm.home(0.5)
    q = arm.controller.q_deg.copy()
    arm.alive["egm"] = False  # droid-egm dies: nothing answers the controller, nothing cycles
    arm.sched.run_for(1.1)  # the twin's comm_timeout_s is 1 s (the cell's), its restart_s 0.2 s
    assert arm.controller.timeouts == 1 and not arm.controller.guiding
    arm.alive["egm"] = True
    arm.sched.run_for(0.5)
    assert arm.controller.guiding and arm.controller.timeouts == 1  # RAPID's loop started it again
    assert int(arm.status["fault"]) == 0 and np.max(np.abs(arm.controller.q_deg - q)) < 0.01  # nothing moved


def _cell_without_twin(tmp_path) -> Path:
    text = CELL.read_text().replace('type = "abb_egm"', 'type = "karel_s400_unused"')
    p = tmp_path / "no_twin.toml"
    p.write_text(text)
    return p


def test_a_cell_without_the_abb_egm_device_is_one_line_naming_the_file(tmp_path):
    path = _cell_without_twin(tmp_path)
    with pytest.raises(BadInput) as exc:
        arm_on(path)
    msg = str(exc.value)
    assert str(path) in msg and "[subunits.abb]" in msg and "abb_egm" in msg and "\n" not in msg
