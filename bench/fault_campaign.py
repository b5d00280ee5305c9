"""Fault campaign: N random seeded faults during motion; prints the counts and recovery times.

    nice -n 5 python bench/fault_campaign.py --faults 100 --seed 1 [--json out.json]

Counts that must be 0: runaway, wedged, leaked, unrecovered (droid.faults.campaign
defines them).  Recovery times are figures for docs/safety.md and docs/benchmarks.md.
"""
from __future__ import annotations

import json
import os
import platform
import shutil
import sys
import tempfile
import time
import uuid
from pathlib import Path

from droid.cli import ArgumentParser, bounded_int, seed_int
from droid.faults.campaign import WORKLOADS, Campaign, campaign_cell_text, plan
from droid.faults.cells import seam_campaign_cell_text


def main() -> int:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faults", type=bounded_int(1, 10**6, "faults"), default=100, help="faults to inject")
    ap.add_argument("--seed", type=seed_int, default=1, help="random seed")
    ap.add_argument("--workload", choices=sorted(WORKLOADS), default="move")
    ap.add_argument("--json", metavar="FILE", help="write the full result (every round) here")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="droid-faults-"))
    name = f"fc{uuid.uuid4().hex[:8]}"
    path = tmp / f"{name}.toml"
    cell_text = seam_campaign_cell_text if args.workload == "seamtrack" else campaign_cell_text
    path.write_text(cell_text(name, str(tmp / "run")))
    t0 = time.time()
    try:
        camp = Campaign(path, WORKLOADS[args.workload](), args.seed, log=lambda m: print(m, flush=True))
        # the seam-tracking cell declares a collision guard: droid-guard is paused and killed too
        result = camp.run(plan(args.faults, args.seed, guard=args.workload == "seamtrack"))
    finally:
        if not os.environ.get("KEEP"):
            shutil.rmtree(tmp, ignore_errors=True)
    result.update(machine=f"{platform.node()} {platform.machine()} {os.cpu_count()} CPUs, "
                          f"Python {platform.python_version()}, {platform.platform()}",
                  date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(t0)),
                  wall_s=round(time.time() - t0, 1), seed=args.seed, workload=args.workload)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    short = {k: v for k, v in result.items() if k != "rounds"}
    print(json.dumps(short, indent=1))
    return 0 if not (result["runaway"] or result["wedged"] or result["leaked"] or result["unrecovered"]) else 1


if __name__ == "__main__":
    sys.exit(main())
