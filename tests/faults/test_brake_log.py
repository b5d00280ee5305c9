"""The servo's own record of an emergency stop (droid.subunits.reis.brake_log), in lockstep."""
from __future__ import annotations

import numpy as np

from droid.sim.reis.lockstep import homed_rigid_cell, min_jerk_waypoints
from droid.subunits.reis.brake_log import BrakeRecorder
from droid.subunits.reis.servo_params import Mode
from droid.subunits.reis.servo_planner import braking_ticks

def _homed():
    # rigid drives: on the compliant arm the links' spring-back after a hard braking stop nudges
    # the motors a few counts, which the recorder rightly logs as a second, tiny motion
    return homed_rigid_cell()


def _move(ls, n_commands: int | None, seconds: float = 2.0):
    """A 30000-count move of joint 1 (and 60000 of joint 6) in 2 s, cut after ``n_commands``
    commands; returns the recorder's events, fed tick by tick as the servo shell does."""
    start = np.asarray(ls.servo.encoder_cmd)
    wp = min_jerk_waypoints(start, start + [30000, 0, 0, 0, 0, 60000], seconds)
    rec = BrakeRecorder()
    events = []
    per_cmd = ls.base_hz // 60
    n = len(wp) + 60
    for c in range(n):
        arrived = n_commands is None or c < n_commands
        if arrived:
            ls.servo.command(Mode.NORMAL, tuple(int(x) for x in wp[min(c, len(wp) - 1)]))
        tr = ls.run(per_cmd / ls.base_hz)
        for i in range(len(tr)):
            ev = rec.step(ls.servo.tick - len(tr) + 1 + i, arrived and i == 0, bool(tr.starved[i]),
                          tr.encoder_pos[i])
            if ev is not None:
                events.append(ev)
    return events


def test_a_cut_command_stream_is_recorded_as_one_braked_halt_within_100_ms():
    ls = _homed()
    try:
        events = _move(ls, n_commands=40)  # mid-move, near peak speed
    finally:
        ls.close()
    assert len(events) == 1
    ev = events[0]
    assert ev.last_command_tick < ev.starved_tick <= ev.moving_tick < ev.standstill_tick <= ev.settled_tick
    assert ev.peak_speed_counts_per_tick >= 50  # it was moving fast
    # the queue (one period) + the coast + the braking profile + the velocity window
    params = ls.servo.params
    bound = 9 + params.starve_grace_ticks + int(braking_ticks(
        np.full(6, ev.peak_speed_counts_per_tick), params.brake_decel_counts_per_tick2).max()) + 10
    assert ev.stop_ticks <= bound, ev
    assert ev.stop_ms <= 100.0, ev


def test_an_uninterrupted_move_records_one_planned_halt_at_its_end():
    ls = _homed()
    try:
        events = _move(ls, n_commands=None)
    finally:
        ls.close()
    assert len(events) == 1
    assert events[0].starved_tick == -1  # never braked
