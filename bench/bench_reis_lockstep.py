"""Lockstep speed and servo tracking of the simulated Reis arm.

Prints, for one seed:
  * homing from a random power-up pose: simulated and wall seconds;
  * a 2 s minimum-jerk move of all six joints: lockstep speed (simulated
    seconds per wall second), following error (max and RMS, counts and joint
    degrees), final error;
  * the cost of one servo core step and of one 2 ms plant advance (us), the
    budget the real-time droid-servo / droid-sim shells work within.

Timing is measured here, never in tests (helper-common: a shared 2-core
machine).  Usage: PYTHONPATH=. python bench/bench_reis_lockstep.py [--seed N] [--json]
"""
from __future__ import annotations

import json
import platform
import time

import numpy as np

from droid.cli import ArgumentParser, MAX_MOVE_S, duration_s, run, seed_int
from droid.sim.reis.lockstep import make_reis_cell, min_jerk_waypoints, run_homing, waypoint_commander
from droid.subunits.reis.servo_params import Mode

MOVE_DEG = np.array([60.0, 45.0, -50.0, 90.0, 70.0, 120.0])
COUNTS_PER_DEG = 100 * 4000 / 360


def bench(seed: int, move_s: float) -> dict:
    ls = make_reis_cell(seed=seed)
    ls.run(0.05)
    t = time.perf_counter()
    run_homing(ls)
    home_wall = time.perf_counter() - t
    if not ls.servo.homed:
        raise SystemExit(f"homing failed: fault {ls.servo.fault.name}")
    home_sim = ls.time_s - 0.05

    m = np.asarray(ls.servo.params.joint_to_counts)
    start = np.asarray(ls.servo.encoder_cmd)
    goal = start + np.rint(m @ MOVE_DEG).astype(np.int64)
    wp = min_jerk_waypoints(start, goal, move_s)
    settle_s = 0.5
    t = time.perf_counter()
    tr = ls.run(move_s + settle_s, waypoint_commander(wp, Mode.NORMAL, first_index=ls.command_index))
    move_wall = time.perf_counter() - t
    moving = tr.t_s - tr.t_s[0] <= move_s
    fe = tr.following_error[moving]
    final = goal - np.asarray(ls.servo.encoder_pos)

    # the same move again without recording a trace (the experiment-runner case)
    start2 = np.asarray(ls.servo.encoder_cmd)
    back = min_jerk_waypoints(start2, start, move_s)
    t = time.perf_counter()
    ls.run(move_s + settle_s, waypoint_commander(back, Mode.NORMAL, first_index=ls.command_index), record=False)
    bare_speed = (move_s + settle_s) / (time.perf_counter() - t)

    # per-call costs
    servo, bus, plant = ls.servo, ls.bus, ls.plant
    n = 2000
    t = time.perf_counter()
    for _ in range(n):
        servo.step(bus.read_encoders_raw(), bus.read_limit_switches())
    servo_us = (time.perf_counter() - t) / n * 1e6
    t = time.perf_counter()
    for _ in range(n):
        plant.advance(0.002)
    plant_us = (time.perf_counter() - t) / n * 1e6

    return {
        "seed": seed,
        "machine": f"{platform.node()} {platform.machine()} {platform.python_version()}",
        "homing_sim_s": round(home_sim, 3),
        "homing_wall_s": round(home_wall, 3),
        "homing_speed_x": round(home_sim / home_wall, 1),
        "move_s": move_s,
        "move_deg": MOVE_DEG.tolist(),
        "lockstep_speed_x": round((move_s + settle_s) / move_wall, 1),
        "lockstep_speed_unrecorded_x": round(bare_speed, 1),
        "fe_max_counts": np.abs(fe).max(axis=0).tolist(),
        "fe_rms_counts": np.round(np.sqrt((fe.astype(float) ** 2).mean(axis=0)), 1).tolist(),
        "fe_max_deg": np.round(np.abs(fe).max(axis=0) / COUNTS_PER_DEG, 4).tolist(),
        "final_error_counts": final.tolist(),
        "starved_ticks": int(tr.starved.sum()),
        "servo_step_us": round(servo_us, 1),
        "plant_advance_2ms_us": round(plant_us, 1),
    }


@run
def main(argv=None) -> int:
    parser = ArgumentParser(prog="bench_reis_lockstep", description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=seed_int, default=1, help="random seed")
    parser.add_argument("--move-s", type=duration_s(MAX_MOVE_S), default=2.0, help="move duration [s]")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args(argv)
    r = bench(args.seed, args.move_s)
    if args.json:
        print(json.dumps(r))
        return 0
    # Alike in shape only to other benches' output: this bench's own figures, one line each.
    print(f"machine               {r['machine']}")
    print(f"homing                {r['homing_sim_s']} s simulated in {r['homing_wall_s']} s wall "
          f"({r['homing_speed_x']}x real time)")
    print(f"{r['move_s']} s move (deg)       {r['move_deg']}")
    print(f"lockstep speed        {r['lockstep_speed_x']}x real time (simulated s per wall s), "
          f"{r['lockstep_speed_unrecorded_x']}x without a trace")
    print(f"following error max   {r['fe_max_counts']} counts")
    print(f"                      {r['fe_max_deg']} joint deg")
    print(f"following error rms   {r['fe_rms_counts']} counts")
    print(f"final error           {r['final_error_counts']} counts; starved ticks {r['starved_ticks']}")
    print(f"servo core step       {r['servo_step_us']} us (budget 2000 us at 500 Hz)")
    print(f"plant advance 2 ms    {r['plant_advance_2ms_us']} us (4 substeps)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
