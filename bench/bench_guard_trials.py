"""200 seeded lockstep trials of the collision guard's protective stop (issue 41; docs/guard.md).

100 head-on and 100 crossing courses (droid.experiments.guard_trial: the reis_pair cell with
its arms' reaches overlapping, the real planners, servos and plants, droid-guard's station),
seeds 0..99 each.  Prints every trial that broke the stated limit or faulted a servo, and the
count kept, the least and median true separation [mm].  Target: 200/200 kept.

    nice -n 10 .venv/bin/python bench/bench_guard_trials.py [--n 100]
"""
from __future__ import annotations

import time

import numpy as np

from droid.cli import ArgumentParser, bounded_int
from droid.experiments.guard_trial import COURSES, SPEED, GuardTrials


def main() -> None:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=bounded_int(1, 1_000_000), default=100, help="seeds a kind of course")
    args = ap.parse_args()
    t0 = time.perf_counter()
    trials = GuardTrials()
    rows = []
    for seed in range(args.n):
        for kind in COURSES:
            r = trials.run(kind, seed)
            rows.append(r)
            if r.servo_fault or not r.kept:
                print(f"{kind} seed {seed}: least {r.min_true_mm:.1f} mm (limit {r.limit_mm:g}), "
                      f"stopped {r.stopped}, servo fault {r.servo_fault}", flush=True)
                if r.servo_fault:  # a faulted servo needs a power cycle: a fresh cell
                    trials.close()
                    trials = GuardTrials()
    trials.close()
    d = np.array([r.min_true_mm for r in rows])
    kept = sum(r.kept and not r.servo_fault for r in rows)
    print(f"{kept}/{len(rows)} kept the stated limit ({rows[0].limit_mm:g} mm); stopped {sum(r.stopped for r in rows)}; "
          f"servo faults {sum(r.servo_fault for r in rows)}; least {d.min():.1f} mm, median {np.median(d):.1f} mm; "
          f"speeds {SPEED}; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
