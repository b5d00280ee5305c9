"""How long one full pass of CPython's cyclic collector takes in each program of the default cell,
with and without the start-up heap frozen (droid.brain.runtime.rt.freeze_heap; issue 40).

The collector runs inside whatever allocation crosses its threshold, so a full (generation-2)
pass is a stall of the loop it lands in, at the loop's priority.  For each program a child
process imports the program's module (what the program has loaded when its loop starts),
builds fresh reference cycles (between 1 and 2 times ``--garbage``, a different count every
repetition, so no pass meets the same heap twice), and times ``gc.collect()``:
once as the heap stands (what an unfrozen program's pass walks) and once after
``freeze_heap()`` with the same amount of fresh garbage made again.  Printed per program: the
objects walked and the pass's time [ms], min / median / max over ``--reps`` children, both
ways, beside the machine's floor (cyclictest) before and after.  Timing never decides a test.

    .venv/bin/python bench/bench_gc_pause.py [--reps 5] [--garbage 2000]
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.floor import cyclictest_floor, when_and_load  # noqa: E402
from droid.cli import ArgumentParser, bounded_int  # noqa: E402

#: the default cell's programs (module, as pyproject.toml's console scripts name them)
PROGRAMS = {
    "droid-sim": "droid.sim.world",
    "droid-heartbeat": "droid.brain.runtime.heartbeat",
    "droid-remote": "droid.brain.runtime.remote",
    "droid-servo": "droid.subunits.reis.servo_prog",
    "droid-servo-agent": "droid.subunits.reis.servo_agent",
    "droid-planner": "droid.arm.planner",
    "droid-agent": "droid.subunits.agent",
    "droid-gmf1-serial": "droid.subunits.gmf1.serial_prog",
    "droid-ft": "droid.subunits.ft.prog",
    "droid-seamtrack": "droid.tasks.seamtrack",
}

CHILD = r"""
import gc, importlib, json, sys, time
importlib.import_module(sys.argv[1])
n = int(sys.argv[2])
from droid.brain.runtime.rt import freeze_heap

class Node:
    pass

def garbage(k):
    for _ in range(k):
        a, b = Node(), Node()
        a.other, b.other = b, a

def timed_pass():
    walked = len(gc.get_objects())
    t = time.perf_counter()
    gc.collect()
    return walked, (time.perf_counter() - t) * 1e3

gc.disable()  # no pass but the timed ones
gc.collect()
garbage(n)
before = timed_pass()
freeze_heap()
garbage(n)
after = timed_pass()
print(json.dumps({"walked": before[0], "ms": before[1], "walked_frozen": after[0], "ms_frozen": after[1]}))
"""


def one(module: str, garbage: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, module, str(garbage)], capture_output=True, text=True,
                         timeout=300, cwd=ROOT, env={**os.environ, "DROID_NO_GC_FREEZE": "0"})
    if out.returncode != 0:
        raise SystemExit(f"bench_gc_pause: {module}: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout)


def mmm(xs: list[float]) -> str:
    return f"{min(xs):6.2f} / {statistics.median(xs):6.2f} / {max(xs):6.2f}"


def main() -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=bounded_int(1, 100), default=5, help="children per program")
    ap.add_argument("--garbage", type=bounded_int(0, 1_000_000), default=2000,
                    help="reference cycles made before each timed pass (scaled per repetition)")
    args = ap.parse_args()
    print(f"bench_gc_pause: {when_and_load()}")
    print(f"before: {cyclictest_floor(3.0, 1000)}", flush=True)
    print(f"{'program':20s} {'objects walked':>15s} {'full pass [ms] min/med/max':>27s}   "
          f"{'frozen: walked':>15s} {'full pass [ms] min/med/max':>27s}")
    for prog, module in PROGRAMS.items():
        rows = [one(module, args.garbage * (1000 + 137 * k % 1000) // 1000) for k in range(args.reps)]
        print(f"{prog:20s} {int(statistics.median(r['walked'] for r in rows)):15d} {mmm([r['ms'] for r in rows]):>27s}   "
              f"{int(statistics.median(r['walked_frozen'] for r in rows)):15d} "
              f"{mmm([r['ms_frozen'] for r in rows]):>27s}", flush=True)
    print(f"after: {cyclictest_floor(3.0, 1000)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
