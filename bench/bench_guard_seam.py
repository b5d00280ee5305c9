"""The collision guard beside the seam-tracking trials of the sim cell (issue 41; docs/guard.md).

Each of the layout's seven start positions is run as a lockstep seam-tracking trial (the
``fast`` Reis model, 10 mm/s; droid.experiments.trial) with the guard's core
(droid.guard.core, the sim cell's ``[guard]`` bodies: the Reis's links, torch and sensor; the
Fanuc's links and the held workpiece box; the floor) stepped on every tick with the Reis's
Status joints and the GMF1's true joints.  The guard only watches here (it writes no fault):
the trial's result is the one it always was, and the figure is whether the guard *would* have
stopped it -- its trips, the least distance and its pair.

    nice -n 10 .venv/bin/python bench/bench_guard_seam.py [--arm fast|full]
"""
from __future__ import annotations

import time

import numpy as np

from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.cli import ArgumentParser
from droid.experiments import trial as T
from droid.guard.station import guard_core

POSITIONS = ("i", "ii", "iii", "iv", "v", "vi", "vii")


def main() -> None:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", default="fast", choices=("fast", "full"))
    ap.add_argument("--positions", default=",".join(POSITIONS), help="comma-separated (default: all seven)")
    args = ap.parse_args()
    core = guard_core(load_cell(BUNDLED_CELLS / "sim.toml"))
    seen: dict = {}
    orig = T._LockstepTrial.task

    def task(self, tick):  # the trial's own tick, then the guard's look at both arms
        orig(self, tick)
        if self.holder is None:
            return
        q = {"arm1": np.asarray(self.arm.status_joints(), float),
             "gmf1": np.asarray(self.holder.g.controller.q_deg, float)}
        v = core.step(q)
        if v.distance_mm < seen["min"]:
            seen["min"], seen["pair"] = v.distance_mm, v.pair

    T._LockstepTrial.task = task
    try:
        for pos in args.positions.split(","):
            core.reset()
            core.release()
            core.trips = 0
            seen.update(min=np.inf, pair=None)
            t0 = time.perf_counter()
            r = T.run_trial(T.TrialConfig(trial_id=f"guard-{pos}", position=pos, speed_mm_s=10.0, arm=args.arm))
            print(f"position {pos}: {r.stop_reason}; guard trips {core.trips}, least {seen['min']:.1f} mm "
                  f"({' with '.join(seen['pair'])}); {time.perf_counter() - t0:.0f} s", flush=True)
    finally:
        T._LockstepTrial.task = orig


if __name__ == "__main__":
    main()
