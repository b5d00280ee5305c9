"""The GMF1 holder in the loop of a lockstep trial (issue 13 item 5): its cost, figures not verdicts.

Runs the same trial (position i, 16 mm/s, 300 mm, the ideal lead sensor, the fast arm) with the
exact holder (``holder="fixed"``), with the GMF1 through its controller and encoders standing
still (``"gmf1"``), and with the GMF1 moving the workpiece at (1, -1, 0.5) mm/s through KAREL
(plus mode); prints wall time, simulated time, the speed-up and the tracking RMS of each.
Usage: PYTHONPATH=. python bench/bench_holder.py [--repeat 3]
"""
from __future__ import annotations

import os
import platform
import time

from droid.cli import ArgumentParser, bounded_int, run
from droid.experiments.trial import TrialConfig, run_trial
from droid.tasks.seam.report import summarize

CASES = (
    ("fixed", dict(holder="fixed")),
    ("gmf1 still", dict(holder="gmf1")),
    ("gmf1 moving (plus)", dict(holder="gmf1", mode="plus", holder_mm_s=(1.0, -1.0, 0.5))),
)


@run
def main(argv=None) -> int:
    p = ArgumentParser(prog="bench_holder", description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=bounded_int(1, 1000, "runs"), default=3,
                   help="runs per case (the fastest is shown)")
    args = p.parse_args(argv)
    print(f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.machine()}, "
          f"{os.cpu_count()} CPU, Python {platform.python_version()}, load {os.getloadavg()[0]:.1f}")
    print("| holder | simulated [s] | wall [s] | x real time | lateral RMS [mm] |")
    print("|---|---|---|---|---|")
    for name, kw in CASES:
        best = None
        for _ in range(args.repeat):
            r = run_trial(TrialConfig("bench", "i", 16.0, length_mm=300.0, sensor="ideal", **kw))
            if best is None or r.wall_s < best.wall_s:
                best = r
        su = summarize(best.rows, stop_reason=best.stop_reason, camera_to_tcp_mm=best.camera_to_tcp_mm)
        print(f"| {name} | {best.sim_s:.1f} | {best.wall_s:.2f} | {best.speedup:.0f} | {su.rms_lateral_mm:.3f} |")
    return 0


if __name__ == "__main__":
    main()
