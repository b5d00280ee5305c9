"""The servo core driving the simulated arm in lockstep (thesis §4.1.5).

Plant at 2 kHz, servo at 500 Hz, watchdog at 50 Hz, commands at 60 Hz, all on
a 6 kHz virtual clock (droid.sim.reis.lockstep).

Position tolerance.  The wrist-centre point (WCP) depends on joints 1-3 only;
its lever arms are at most 1140 mm (joints 1 and 2: 600 + 540 mm) and 540 mm
(joint 3).  One motor count is 1/(100*4000/360) deg = 1.571e-5 rad of joint,
so a one-count error on all three joints moves the WCP at most
(1140 + 1140 + 540) mm * 1.571e-5 = 0.044 mm.  A final error of
POSITION_TOL_COUNTS = 2 counts per joint therefore keeps the WCP within
0.089 mm <= 0.1 mm.  The tests also check the WCP error directly with the DH
model of Table 4.1.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from droid.sim.reis.lockstep import (
    constant_commander,
    make_reis_cell,
    NEAR_SWITCH_OFFSET_DEG,
    min_jerk_waypoints,
    run_homing,
    waypoint_commander,
)
from droid.sim.reis.plant import ReisPlantParams
from droid.subunits.reis.servo_params import Fault, Mode, ServoParams
from droid.subunits.reis.servo_planner import braking_distance_counts, braking_ticks



#: The servo's count logic is checked on rigid drives (motor and link angles agree, so a
#: count-exact homing and positioning are measurable); the compliant arm's homing and
#: positioning (harmonic-drive deflection under gravity) are in test_plant_dynamics.py.
RIGID = ReisPlantParams(compliance=False)


def make_cell(seed=0, near_switch=True, **kw):
    """A lockstep cell; by default powered up near the switches (fast homing)."""
    kw.setdefault("plant_params", RIGID)
    if near_switch and "initial_joint_deg" not in kw:
        kw["near_switch_offset_deg"] = NEAR_SWITCH_OFFSET_DEG
    return make_reis_cell(seed=seed, **kw)


home = run_homing

POSITION_TOL_COUNTS = 2
WCP_TOL_MM = 0.1

# Table 4.1: (theta offset [deg], d [mm], a [mm], alpha [deg]) for joints 1..5
DH = [(0, 725, 0, 90), (90, 0, 600, 0), (0, 0, 0, 90), (0, 540, 0, -90), (0, 0, 0, 90)]


def wcp_mm(q_deg) -> np.ndarray:
    """Wrist-centre position [mm] from joint angles [deg] (thesis eq. 4.1-4.2)."""
    t = np.eye(4)
    for (off, d, a, alpha), q in zip(DH, q_deg):
        th, al = np.radians(q + off), np.radians(alpha)
        ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(al), np.sin(al)
        t = t @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])
    return t[:3, 3]


def test_wcp_tolerance_derivation_holds():
    rng = np.random.default_rng(0)
    minv = np.linalg.inv(np.asarray(ServoParams().joint_to_counts))
    for _ in range(50):
        q = rng.uniform(-90, 90, 6)
        dm = rng.choice([-POSITION_TOL_COUNTS, POSITION_TOL_COUNTS], 6)
        assert np.linalg.norm(wcp_mm(q + minv @ dm) - wcp_mm(q)) <= WCP_TOL_MM


# -- homing ------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_homing_from_random_power_up_finds_the_switches(seed):
    ls = make_cell(seed=seed, near_switch=False)  # +-15 deg about the centre, arbitrary counters
    ls.run(0.05)
    home(ls)
    s, plant = ls.servo, ls.plant
    assert s.homed and s.fault == Fault.NONE and s.mode == Mode.NORMAL
    # home-relative encoder position vs the true motor position: the zero is right
    err = np.asarray(s.encoder_pos) - plant.motor_counts
    assert np.all(np.abs(err) <= 2.0), err
    # and the joints sit on their switch edges (joint i was left there, within the
    # 1 % coupling drift caused by later joints)
    sw = np.asarray(plant.params.switch_joint_deg)
    assert np.all(np.abs(plant.joint_deg - sw) < 0.25)


def test_homing_backs_off_an_active_switch_and_goes_wrist_first():
    pp = RIGID
    ls = make_cell(seed=5, plant_params=pp)  # joints 1,3,5 start past (on) their switch
    start_on = ls.plant.limit_switches
    assert start_on == (True, False, True, False, True, False)
    ls.run(0.05)
    seen_joints, backoffs = [], set()
    cmd = constant_commander(Mode.HOME)
    while not ls.servo.homed and ls.time_s < 40:  # ~20 s with the edges bracketed at rest
        ls.run(0.01, cmd, record=False)
        j = ls.servo.homing_joint
        if j is not None and (not seen_joints or seen_joints[-1] != j):
            seen_joints.append(j)
        if j is not None and ls.servo._homing.phase.name == "BACKOFF":
            backoffs.add(j)
    assert ls.servo.homed
    assert seen_joints == [5, 4, 3, 2, 1, 0]  # ServoParams.home_order: wrist first
    assert backoffs == {0, 2, 4}
    assert np.all(np.abs(np.asarray(ls.servo.encoder_pos) - ls.plant.motor_counts) <= 2.0)


def test_repeated_home_commands_do_not_restart_homing(homed_cell):
    ls = homed_cell
    zero = ls.servo.zero_counts
    ls.run(0.5, constant_commander(Mode.HOME))  # the agent keeps sending HOME
    assert ls.servo.homed and ls.servo.zero_counts == zero
    ls.run(0.05, constant_commander(Mode.NORMAL, ls.servo.encoder_cmd))
    ls.run(0.05, constant_commander(Mode.HOME))  # a new HOME after another mode re-homes
    assert not ls.servo.homed and ls.servo.homing


def test_homing_fails_cleanly_when_no_switch_is_found():
    ls = make_cell(seed=6, servo_params=ServoParams(home_search_limit_counts=3000), near_switch=False,
                   initial_joint_deg=[0, 0, 0, 0, 0, -60.0])
    ls.run(0.05)
    home(ls, max_s=5)
    assert ls.servo.fault == Fault.HOME_SWITCH_NOT_FOUND
    assert not ls.servo.homed
    assert ls.servo.step(ls.bus.read_encoders_raw(), ls.bus.read_limit_switches()) == (0,) * 6
    assert not ls.servo.command(Mode.JOG, (10,) * 6)
    assert ls.servo.command(Mode.OFF)
    assert ls.servo.fault == Fault.NONE


# -- moves -------------------------------------------------------------------------------
def move(ls, goal_counts, seconds, settle_s=0.4, mode=Mode.NORMAL):
    start = np.asarray(ls.servo.encoder_cmd)
    wp = min_jerk_waypoints(start, goal_counts, seconds)
    tr = ls.run(seconds + settle_s, waypoint_commander(wp, mode, first_index=ls.command_index))
    return wp, tr


def test_joint_move_reaches_its_target_along_the_planned_ramp(homed_cell):
    ls = homed_cell
    minv = np.linalg.inv(np.asarray(ls.servo.params.joint_to_counts))
    goal_deg = np.array([40.0, -25.0, 30.0, -60.0, 45.0, 90.0])
    goal = np.rint(np.asarray(ls.servo.params.joint_to_counts) @ goal_deg).astype(int)
    wp, tr = move(ls, goal, 1.5)
    # final error within the derived tolerance, and the WCP within 0.1 mm
    final = goal - np.asarray(ls.servo.encoder_pos)
    assert np.all(np.abs(final) <= POSITION_TOL_COUNTS), final
    assert np.linalg.norm(wcp_mm(ls.plant.joint_deg) - wcp_mm(minv @ goal)) <= WCP_TOL_MM
    # along the planned ramp: the target passes exactly through every way-point
    # whose command period ends on a servo tick (every third at 500/60 Hz), in
    # order, moves monotonically from start to goal (min-jerk is monotone), and
    # the queue never ran dry
    cmd = tr.encoder_cmd
    hits = [c for c in range(len(wp)) if (cmd == wp[c]).all(axis=1).any()]
    assert len(hits) >= len(wp) // 3 - 1
    first_hit = [int(np.argmax((cmd == wp[c]).all(axis=1))) for c in hits]
    assert first_hit == sorted(first_hit)
    step = np.diff(cmd, axis=0)
    assert np.all(step * np.sign(goal - cmd[0]) >= 0)
    assert not tr.starved.any()
    assert np.all(np.abs(step) <= np.asarray(ls.servo.params.max_speed_counts_per_tick))
    # following error stays small during the move (peak speed 75 deg/s on joint 6; its
    # breakaway from stiction under the sensor head's off-axis weight peaks at ~55 counts)
    assert np.abs(tr.following_error).max() <= 60


def test_following_error_bounded_during_a_fast_move(homed_cell):
    ls = homed_cell
    goal = np.asarray(ls.servo.encoder_cmd) + np.rint(
        np.asarray(ls.servo.params.joint_to_counts) @ [80, 60, -70, 120, -100, 150]
    ).astype(int)
    _, tr = move(ls, goal, 1.6)  # ~94 deg/s on joints 1-3, ~175 deg/s on the wrist
    fe = np.abs(tr.following_error).max(axis=0)
    assert np.all(fe <= 300), fe  # 0.27 joint degrees
    assert np.all(np.abs(goal - np.asarray(ls.servo.encoder_pos)) <= POSITION_TOL_COUNTS)
    assert ls.servo.fault == Fault.NONE


def test_badly_tuned_loop_shows_gravity():
    """Without integral action the forearm sags by gravity/kp; the tuned loop holds."""
    def hold_error(ki):
        params = replace(ServoParams(), ki_dac_per_count_tick=ki)
        ls = make_cell(seed=8, servo_params=params, initial_joint_deg=[0, 20, 10, 0, 0, 0])
        ls.run(1.0, constant_commander(Mode.JOG))
        return np.asarray(ls.servo.following_error)

    p_only = hold_error((0.0,) * 6)
    tuned = hold_error(ServoParams().ki_dac_per_count_tick)
    assert abs(p_only[2]) >= 30  # joint 3 carries the unbalanced forearm
    assert abs(p_only[1]) >= 5  # joint 2: the balancer takes most of it
    assert np.all(np.abs(tuned) <= 1)


# -- braking -------------------------------------------------------------------------------
def test_starved_queue_brakes_to_a_stop_and_holds():
    ls = make_cell(seed=4)
    ls.run(0.05)
    params = ls.servo.params
    per_cmd = np.array([1250, -1000, 1250, 2500, -2500, 2000])  # 150, 120, .. counts/tick
    ramp = np.rint(np.outer(np.minimum(np.arange(1, 61) / 20, 1.0), per_cmd)).astype(int)
    n_cmds = 40
    tr = ls.run(1.5, waypoint_commander(ramp, Mode.JOG, first_index=ls.command_index, stop_after=n_cmds))
    i0 = int(np.argmax(tr.starved))  # first tick of the braking profile
    assert i0 > 0 and not tr.starved[:i0].any()
    v0 = tr.encoder_cmd[i0 - 1] - tr.encoder_cmd[i0 - 2]
    assert np.array_equal(np.abs(v0), np.abs(per_cmd) * 3 // 25)  # at full jog speed
    # the last command's goal, the coast, then the braking distance -- no further
    goal = tr.encoder_cmd[0] + ramp[:n_cmds].sum(axis=0)
    coast = params.starve_grace_ticks * v0
    limit = np.abs(goal + coast - tr.encoder_cmd[i0 - 1]) + braking_distance_counts(v0, params.brake_decel_counts_per_tick2)
    travel_cmd = np.abs(tr.encoder_cmd[-1] - tr.encoder_cmd[i0 - 1])
    assert np.all(travel_cmd <= limit + 1)
    overshoot = np.max(np.sign(v0) * (tr.encoder_pos[i0:] - tr.encoder_cmd[-1]), axis=0)
    assert np.all(overshoot <= 60), overshoot  # the arm stops where the profile stops (0.05 deg)
    # commanded velocity reaches zero within the braking time; the arm within 0.1 s more
    stop = braking_ticks(v0, params.brake_decel_counts_per_tick2).astype(int)
    vel_cmd = np.diff(tr.encoder_cmd[i0 - 1 :], axis=0)
    for j in range(6):
        assert np.all(vel_cmd[stop[j]:, j] == 0)
    settle = i0 + int(stop.max()) + 150  # 0.3 s after the profile stopped
    # and holds, within the derived tolerance (the wrist now carries gravity against Coulomb
    # friction: the integral walks a stuck joint back in steps of a count or two)
    assert np.all(np.abs(tr.encoder_pos[settle:] - tr.encoder_cmd[-1]) <= POSITION_TOL_COUNTS)
    assert tr.braking[i0] and not tr.braking[-1] and tr.starved[-1]


def test_late_commands_are_bridged_without_braking(homed_cell):
    """A command stream with 2-3 ms hiccups (a host stall) coasts, never brakes."""
    ls = homed_cell
    start = np.asarray(ls.servo.encoder_cmd)
    goal = start + 20000
    wp = min_jerk_waypoints(start, goal, 1.0)
    parts = []
    base_per_cmd = ls.base_hz // 60  # 100 base ticks
    for c in range(90):
        cmd = (Mode.NORMAL, tuple(int(x) for x in wp[min(c, len(wp) - 1)]))
        delay = (c % 4) * 12  # 0, 1, 2, 3 servo ticks late, in turn
        if delay:
            parts.append(ls.run(delay / ls.base_hz))
        ls.servo.command(*cmd)
        parts.append(ls.run((base_per_cmd - delay) / ls.base_hz))
    starved = np.concatenate([p.starved for p in parts])
    cmd_trace = np.concatenate([p.encoder_cmd for p in parts])
    assert not starved.any()
    # coasting extrapolates the last velocity; re-entering the ramp corrects by
    # the velocity change over the coast (a few counts while decelerating)
    assert np.diff(cmd_trace, axis=0).min() >= -5
    assert np.all(np.abs(goal - np.asarray(ls.servo.encoder_pos)) <= POSITION_TOL_COUNTS)


# -- watchdog -------------------------------------------------------------------------------
def test_watchdog_latch_stops_the_arm_until_power_cycle():
    ls = make_cell(seed=12)
    ls.run(0.3, constant_commander(Mode.JOG, (400,) * 6))
    assert ls.plant.amps_on
    ls.watchdog_running = False  # the watchdog program dies
    tr = ls.run(0.3, constant_commander(Mode.JOG, (400,) * 6))
    off = int(np.argmin(tr.amps_on))
    # the last kick was at most one 20 ms watchdog period before it stopped
    assert 0.08 <= tr.t_s[off] - tr.t_s[0] <= 0.105
    moving = tr.encoder_pos[-1] - tr.encoder_pos[-40]
    assert np.all(moving == 0)  # braked and stopped
    assert np.any(np.abs(tr.dac[off:]) > 500)  # although the servo drives hard
    assert ls.servo.fault == Fault.FOLLOWING_ERROR  # (until it notices the arm does not follow)
    ls.watchdog_running = True
    ls.watchdog.rearm()
    tr = ls.run(0.3, constant_commander(Mode.JOG, (400,) * 6))
    assert not tr.amps_on.any()  # latched until the power cycle
    assert np.all(tr.encoder_pos[-1] == tr.encoder_pos[0])
    ls.plant.power_cycle()
    ls.run(0.05)
    # the servo is still faulted, so the watchdog does not arm the amplifiers again
    assert ls.servo.fault != Fault.NONE
    assert not ls.plant.amps_on


def test_dead_servo_stops_the_watchdog():
    ls = make_cell(seed=13)
    ls.run(0.2, constant_commander(Mode.JOG, (300,) * 6))
    ls.servo_running = False  # the servo process dies with its DACs still set
    tr = ls.run(0.3)
    assert ls.watchdog.servo_dead
    assert not ls.plant.amps_on
    assert np.all(ls.plant.motor_speed_counts_per_s == 0)


def test_following_error_fault_zeroes_dacs_and_drops_the_watchdog():
    ls = make_cell(seed=14)
    ls.run(0.05)
    ls.plant.jam(1)
    tr = ls.run(1.5, constant_commander(Mode.JOG, (0, 400, 0, 0, 0, 0)))
    assert ls.servo.fault == Fault.FOLLOWING_ERROR
    assert np.all(tr.dac[-1] == 0)
    assert not ls.plant.amps_on


# -- roll-over, limits, jog, anti-windup, off ---------------------------------------------
@pytest.mark.parametrize("power_up, delta", [(65300, 3000), (200, -3000)])
def test_rollover_across_the_16_bit_boundary_during_a_move(power_up, delta):
    ls = make_cell(seed=15, encoder_power_up_counts=[power_up] * 6)
    ls.run(0.02)
    start = np.asarray(ls.servo.encoder_cmd)  # (the arm may still be settling under gravity)
    ramp = np.tile(np.full(6, delta // 30), (30, 1))
    tr = ls.run(1.0, waypoint_commander(ramp, Mode.JOG, first_index=ls.command_index))
    raw = tr.encoder_raw
    wrapped = (np.abs(np.diff(raw, axis=0)) > 30000).any(axis=0)
    assert wrapped.all()  # every counter crossed 65535 <-> 0
    assert np.all(np.abs(np.asarray(ls.servo.encoder_pos) - (start + delta)) <= POSITION_TOL_COUNTS)
    # << the 4000-count fault limit; joint 5 peaks at 100 counts (the rigid arm couples it to joint 2,
    # whose derivative gain is sized for the compliant drive: reis_v15.toml [servo.source])
    assert np.abs(tr.following_error).max() < 120
    assert ls.servo.fault == Fault.NONE
    # extended counts match the plant's true motion, with no 65536 jumps
    moved_true = ls.plant.motor_counts - (tr.motor_counts[0])
    moved_servo = np.asarray(ls.servo.encoder_pos) - tr.encoder_pos[0]
    assert np.all(np.abs(moved_true - moved_servo) <= 1.5)


def test_target_limits_clamp_absolute_and_jog_commands():
    lim = 8000  # counts (7.2 deg); the home switches lie inside
    params = replace(ServoParams(), target_min_counts=(-lim,) * 6, target_max_counts=(lim,) * 6)
    ls = make_cell(seed=16, servo_params=params)
    ls.run(0.05)
    home(ls)
    assert ls.servo.homed
    beyond = np.array([1, -1, 1, -1, 1, -1]) * 12000
    _, tr = move(ls, beyond, 1.0, settle_s=0.5)
    assert np.array_equal(ls.servo.encoder_cmd, [lim, -lim, lim, -lim, lim, -lim])
    assert np.abs(tr.encoder_cmd).max() == lim
    assert np.all(np.abs(np.asarray(ls.servo.encoder_pos) - ls.servo.encoder_cmd) <= POSITION_TOL_COUNTS)
    tr = ls.run(0.6, constant_commander(Mode.JOG, (500,) * 6))  # 36 jogs of 500: past +lim
    assert np.array_equal(ls.servo.encoder_cmd, (lim,) * 6)
    assert tr.encoder_cmd.max() == lim


def test_jog_moves_work_before_homing_and_normal_needs_homing():
    ls = make_cell(seed=17)
    ls.run(0.05)
    assert not ls.servo.homed
    assert not ls.servo.command(Mode.NORMAL, (0,) * 6)  # absolute targets need a zero
    start = np.asarray(ls.servo.encoder_cmd)
    jog = np.array([100, -100, 120, -150, 200, -200])  # within the jog acceleration limit
    ramp = np.tile(jog, (30, 1))
    ls.run(1.0, waypoint_commander(ramp, Mode.JOG, first_index=ls.command_index))
    assert np.all(np.abs(np.asarray(ls.servo.encoder_pos) - (start + 30 * jog)) <= POSITION_TOL_COUNTS)
    assert np.array_equal(ls.servo.encoder_cmd, start + 30 * jog)


def test_jog_speed_and_acceleration_are_limited():
    """A full-deflection jog from rest ramps up to the maximum speed instead of
    stepping to it (which would saturate the amplifiers and trip the following
    error), then ramps down when the jog stops, without coming back."""
    ls = make_cell(seed=18)
    ls.run(0.05)
    params = ls.servo.params
    jog = waypoint_commander(np.full((36, 6), 10**6), Mode.JOG, first_index=ls.command_index)
    tr = ls.run(1.0, jog)  # 0.6 s of full jog, then zero deltas
    vmax = np.asarray(params.max_speed_counts_per_tick)
    vel = np.diff(tr.encoder_cmd, axis=0)
    assert np.all(np.abs(vel) <= vmax)
    assert np.any(np.all(vel >= vmax - 1, axis=1))  # it does reach full speed
    # velocity is constant within a command period and changes between periods
    # by at most accel * period (25/3 ticks), rounding aside
    accel = np.asarray(params.jog_accel_counts_per_tick2)
    assert np.all(np.abs(np.diff(vel, axis=0)) <= accel * 25 / 3 + 2)
    assert np.all(vel >= 0)  # stops without reversing
    assert np.all(vel[-50:] == 0)
    assert ls.servo.fault == Fault.NONE
    assert np.abs(tr.following_error).max() < 300


def test_blocked_joint_does_not_wind_up_the_integral():
    ls = make_cell(seed=19)
    ls.run(0.5, constant_commander(Mode.JOG))
    limit = np.asarray(ls.servo.params.integral_limit_dac)
    ls.plant.jam(2)
    jam_at = ls.plant.motor_counts[2]
    integrals = []
    push = waypoint_commander(np.tile([0, 0, 100, 0, 0, 0], (15, 1)), Mode.JOG, first_index=ls.command_index)
    for _ in range(30):  # 1.5 s blocked, finally 1500 counts short: kp*e saturates the DAC
        ls.run(0.05, push)
        integrals.append(ls.servo.integral_dac[2])
    assert ls.servo.dac[2] == 2047
    assert np.all(np.abs(integrals) <= limit[2])
    assert len(set(integrals[-15:])) == 1  # frozen while saturated, not winding up
    # take the target back to the blocked position, then release the joint: the
    # kick is bounded by the integral limit (the integral did charge while the
    # error shrank unsaturated), and the joint settles back on target
    back = waypoint_commander(np.tile([0, 0, -100, 0, 0, 0], (15, 1)), Mode.JOG, first_index=ls.command_index)
    ls.run(0.4, back)
    assert abs(ls.servo.integral_dac[2]) <= limit[2]
    ls.plant.jam(2, False)
    tr = ls.run(0.6, back)
    assert np.max(np.abs(tr.motor_counts[:, 2] - jam_at)) < 300
    assert abs(ls.servo.following_error[2]) <= POSITION_TOL_COUNTS


def test_off_mode_zeroes_dacs_and_restarts_bumplessly():
    ls = make_cell(seed=20, initial_joint_deg=[0, 20, 10, 0, 0, 0])
    ls.run(0.3, constant_commander(Mode.JOG))
    tr = ls.run(0.2, constant_commander(Mode.OFF))
    assert np.all(tr.dac == 0)
    assert np.array_equal(ls.servo.encoder_cmd, ls.servo.encoder_pos)  # target follows the arm
    at_restart = np.asarray(ls.servo.encoder_pos)
    tr = ls.run(0.5, constant_commander(Mode.JOG))
    # the target starts where the arm is (not at the old target): no jump
    assert np.array_equal(tr.encoder_cmd[0], at_restart) or np.abs(tr.following_error[0]).max() <= 60
    assert np.array_equal(ls.servo.encoder_cmd, tr.encoder_cmd[0])
    assert np.all(np.abs(np.asarray(ls.servo.encoder_pos) - ls.servo.encoder_cmd) <= POSITION_TOL_COUNTS)
    assert ls.servo.mode == Mode.JOG


# -- determinism -------------------------------------------------------------------------------
def test_same_seed_same_run():
    def run(seed):
        ls = make_cell(seed=seed)
        ls.run(0.05)
        parts = home(ls)
        goal = np.asarray(ls.servo.encoder_cmd) + 5000
        parts.append(move(ls, goal, 0.5, 0.2)[1])
        return parts

    a, b, c = run(30), run(30), run(31)
    assert len(a) == len(b)
    for pa, pb in zip(a, b):
        for field in ("encoder_pos", "encoder_cmd", "dac", "motor_counts", "encoder_raw"):
            assert np.array_equal(getattr(pa, field), getattr(pb, field))
    assert not np.array_equal(a[0].encoder_raw, c[0].encoder_raw)


def test_after_the_brake_a_far_way_point_is_refused_and_a_near_one_resumes(homed_cell):
    """The servo braked to rest (its command stream stopped mid-move); a NORMAL way-point
    that is not where the arm stands -- the target of a sender that missed the stop -- is
    refused: resuming would start the arm from rest at full ramp speed.  A way-point within
    ``resume_window_counts`` of the arm resumes.  While still braking, a way-point that
    continues the path is taken (a late planner is bridged as before)."""
    ls = homed_cell
    start = np.asarray(ls.servo.encoder_cmd)
    goal = start + 30000
    wp = min_jerk_waypoints(start, goal, 1.0)
    tr = ls.run(1.0, waypoint_commander(wp, Mode.NORMAL, first_index=ls.command_index, stop_after=30))
    assert ls.servo.at_rest  # braked to rest mid-move
    here = np.asarray(ls.servo.encoder_pos)
    assert np.all(np.abs(goal - here) > 1000)
    window = ls.servo.params.resume_window_counts
    assert ls.servo.command(Mode.NORMAL, tuple(int(x) for x in here + window + 1)) is False
    assert ls.servo.command(Mode.NORMAL, tuple(int(x) for x in goal)) is False
    assert ls.servo.refused_resumes == 2
    tr = ls.run(0.2)
    assert np.all(np.abs(tr.encoder_pos - here) <= POSITION_TOL_COUNTS)  # it never moved
    assert tr.starved.all()
    now = np.asarray(ls.servo.encoder_pos)  # where it stands now (it settles by a count)
    near = now + window
    assert ls.servo.command(Mode.NORMAL, tuple(int(x) for x in near)) is True
    tr = ls.run(0.3)
    assert not tr.starved.all()  # it ran the ramp to it (then, fed no more, coasted, braked and held)
    moved = np.asarray(ls.servo.encoder_pos) - now
    assert np.all(moved >= window - POSITION_TOL_COUNTS) and np.all(moved <= 3 * window), moved
    assert ls.servo.refused_resumes == 2


def test_a_way_point_while_still_braking_is_taken(homed_cell):
    ls = homed_cell
    start = np.asarray(ls.servo.encoder_cmd)
    wp = min_jerk_waypoints(start, start + 30000, 1.0)
    ls.run(0.6, waypoint_commander(wp, Mode.NORMAL, first_index=ls.command_index, stop_after=30))
    first = ls.command_index
    # run tick by tick until the brake has begun, then send the path's next way-point
    for _ in range(200):
        if ls.servo.starved:
            break
        ls.run(1 / ls.base_hz * 12)
    assert ls.servo.starved and not ls.servo.at_rest
    assert ls.servo.command(Mode.NORMAL, tuple(int(x) for x in wp[31])) is True
    assert ls.servo.refused_resumes == 0 and first <= ls.command_index
