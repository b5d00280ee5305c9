"""The Reis subunit's program cores in lockstep (issue 4 §6): home, move, brake, watchdog."""
import numpy as np

from droid.brain.db import layouts as L
from droid.sim.lockstep import Scheduler
from droid.sim.reis.cell import LockstepArm
from droid.sim.reis.plant import ReisPlantParams


def make(seed=1):
    s = Scheduler(60.0)
    # rigid drives: count-level arrival checks (the compliant arm: test_plant_dynamics.py)
    return s, LockstepArm(s, seed=seed, plant_params=ReisPlantParams(compliance=False))


def test_home_then_joint_and_cartesian_moves_reach_their_targets():
    s, arm = make()
    assert arm.home()
    cid = arm.command_joint([0, 0, 0, 0, 0, 0], arm.ticks_for(1.5))
    assert arm.move_done(cid, 5)
    T = arm.model.fk([20.0, 10.0, 15.0, 5.0, 30.0, -10.0])
    cid = arm.command_cart(T, arm.ticks_for(2.0))
    assert arm.move_done(cid, 6)
    s.run_for(0.5)  # settle
    err = np.linalg.norm(arm.wcp_global()[:3, 3] - T[:3, 3])
    assert err <= 0.1, f"wrist centre {err:.3f} mm from the target"
    assert int(arm.status["cmd_result"]) == L.CMD_OK


def test_deterministic_for_a_seed():
    runs = []
    for _ in range(2):
        s, arm = make(seed=5)
        arm.home()
        arm.move_done(arm.command_joint([3000, -2000, 1000, 0, 4000, 0], arm.ticks_for(1.0)), 4)
        runs.append((arm.plant.joint_deg.copy(), s.t_ns))
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


def test_link_loss_brakes_and_the_arm_stays_until_a_new_command():
    s, arm = make()
    assert arm.home()
    start = arm.plant.joint_deg.copy()
    cid = arm.command_joint([40000, 0, 0, 0, 0, 60000], arm.ticks_for(6.0))
    s.run_for(1.5)
    arm.alive["link"] = False
    s.run_for(1.0)
    stopped = arm.plant.joint_deg.copy()
    s.run_for(0.5)
    assert np.allclose(arm.plant.joint_deg, stopped, atol=0.01)  # braked to a standstill
    assert abs(stopped[0] - start[0]) < 0.9 * 36.0  # it did not finish the move
    arm.alive["link"] = True
    s.run_for(2.0)
    assert np.allclose(arm.plant.joint_deg, stopped, atol=0.02)  # stays until a new command
    assert int(arm.status["cmd_result"]) == L.CMD_FAILED and int(arm.status["cmd_id"]) == cid
    assert arm.move_done(arm.command_joint([40000, 0, 0, 0, 0, 60000], arm.ticks_for(4.0)), 8)


def test_dead_servo_trips_the_watchdog_latch():
    s, arm = make()
    s.run_for(0.5)
    assert arm.plant.amps_on
    arm.alive["servo"] = False
    s.run_for(0.5)
    assert not arm.plant.amps_on
    assert int(arm.status["fault"]) & L.FAULT_SERVO


def test_a_cut_link_brings_the_arm_to_rest_through_the_braking_profile():
    """Issue 16, docs/safety.md finding 1: when the Brain's ticks stop mid-move, the servo's
    commanded speed falls at the braking profile's rate (in the 60 Hz steps in which every
    way-point reaches the servo), not from full speed to zero within a tick."""
    s, arm = make()
    assert arm.home()
    arm.command_joint([60000, 0, 0, 0, 0, 0], arm.ticks_for(3.0))  # 40 counts per servo tick
    s.run_for(1.5)
    arm.alive["link"] = False
    cmd = []
    for _ in range(300):  # 0.6 s of servo ticks
        s.run_for(1.0 / 500)
        cmd.append(int(arm.servo.encoder_cmd[0]))
    v = np.diff(cmd)  # [counts per servo tick]
    p = arm.servo.params
    step = p.brake_decel_counts_per_tick2[0] * p.servo_rate_hz / p.command_rate_hz  # per period
    assert abs(v[0]) > 2 * step  # it was moving fast
    assert np.all(np.abs(np.diff(v)) <= step + 2), np.diff(v)  # never faster than the profile
    assert np.all(v[-100:] == 0)  # at rest, and it stays
    stop_ticks = int(np.argmax(v == 0))
    assert stop_ticks <= 3 * 9 + abs(v[0]) / p.brake_decel_counts_per_tick2[0] + 9
