#!/usr/bin/env python3
"""Reis motion controller in the real-time process cell (issue 4 §9): prints figures.

  servo lateness    the 500 Hz droid-servo loop's wake-up lateness, p99 and overrun
                    rate, over --seconds (default 60) while the arm moves back and forth
  following error   during a 2 s joint move (encoder_cmd - encoder_pos in the arm's own
                    Status record, sampled at 120 Hz), max per joint [counts]
  command-to-motion from writing a joint command in the Brain's Command record to the
                    first encoder change of more than 5 counts in the arm's Status [ms]

Brings up its own cell (a copy of the built-in sim cell, --fifo to ask for SCHED_FIFO)
and brings it down again.  Record the output with the machine and date in
docs/benchmarks.md.
"""
from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from droid.brain.cell.cellfile import builtin_cell_path, load_cell  # noqa: E402
from droid.brain.db.databases import open_brain, open_local  # noqa: E402
from droid.brain.db.layouts import PROC_STATUS_LAYOUT  # noqa: E402
from droid.brain.db.shmdb import Database, db_name  # noqa: E402
from droid.cli import ArgumentParser, duration_s  # noqa: E402
from droid.tasks.arm import BrainArm  # noqa: E402


def run(*args, timeout=240):
    out = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout)
    if out.returncode:
        raise SystemExit(f"{args}: {out.stderr.strip()}")
    return out


def main():
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=duration_s(), default=60.0, help="duration of the run [s]")
    ap.add_argument("--fifo", action="store_true", help="sched_fifo = true in the cell file")
    args = ap.parse_args()
    name = "bench" + uuid.uuid4().hex[:6]
    tmp = Path(tempfile.mkdtemp())
    text = builtin_cell_path().read_text()
    text = re.sub(r'(?m)^name = "sim"', f'name = "{name}"\nrun_dir = "{tmp}/run"', text, count=1)
    if args.fifo:
        text = text.replace("sched_fifo = false", "sched_fifo = true")
    path = tmp / "cell.toml"
    path.write_text(text)
    print(f"# bench_reis_rt  {time.strftime('%Y-%m-%d %H:%M')}  {platform.node()}  {platform.machine()}  "
          f"{os.cpu_count()} CPUs  Python {platform.python_version()}  load {os.getloadavg()[0]:.1f}"
          f"  SCHED_FIFO {'on' if 'sched_fifo = true' in text else 'off'}")
    run("droid.brain.runtime.launcher", "up", "--cell", str(path))
    try:
        run("droid.tasks.home", "arm1", "--cell", str(path))
        cell = load_cell(path)
        sub = cell.subunit("arm1")
        local = open_local(cell, sub, "ctrl_status")
        proc = Database(db_name(name, "proc", "servo-arm1"), PROC_STATUS_LAYOUT)
        arm = BrainArm(cell, "arm1").connect()
        # command-to-motion latency, 10 samples
        lat = []
        for k in range(10):
            arm.wait_idle(30)
            before = np.asarray(local.read()["encoder_pos"])
            target = np.zeros(6, int)
            target[0] = 8000 if k % 2 == 0 else 0
            t0 = time.monotonic()
            arm.command_joint(target, int(1.0 * 60))
            while np.max(np.abs(np.asarray(local.read()["encoder_pos"]) - before)) <= 5:
                time.sleep(0.0005)
            lat.append((time.monotonic() - t0) * 1e3)
            arm.wait_idle(30)
        print(f"  command-to-motion latency        median {np.median(lat):6.1f} ms   max {max(lat):6.1f} ms   (n={len(lat)})")
        # following error during a 2 s joint move
        arm.wait_idle(30)
        target = np.array([20000, -15000, 12000, 30000, 25000, -40000])
        arm.command_joint(target, 120)
        fe = []
        t_end = time.monotonic() + 2.5
        while time.monotonic() < t_end:
            r = local.read()
            fe.append(np.abs(np.asarray(r["encoder_cmd"]) - np.asarray(r["encoder_pos"])))
            time.sleep(1 / 120)
        fe = np.max(np.array(fe), axis=0)
        print(f"  following error, 2 s joint move  max per joint {fe.tolist()} counts")
        # servo lateness and overruns while moving back and forth
        r0 = proc.read()
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < args.seconds:
            arm.wait_idle(30)
            arm.command_joint(target if k % 2 else np.zeros(6, int), 120)
            k += 1
        r1 = proc.read()
        cycles = int(r1["cycles"]) - int(r0["cycles"])
        over = int(r1["overruns"]) - int(r0["overruns"])
        print(f"  servo loop over {args.seconds:.0f} s: {cycles} cycles, {over} overruns "
              f"({100.0 * over / max(1, cycles + over):.3f} %), worst lateness {int(r1['lateness_max_ns']) / 1e3:.0f} us")
        arm.close()
        proc.close()
        local.close()
    finally:
        run("droid.brain.runtime.launcher", "down", "--cell", str(path))
    log = (tmp / "run" / "logs" / "servo-arm1.log").read_text().strip().splitlines()
    print("  servo loop (its exit report):", log[-1] if log else "(none)")


if __name__ == "__main__":
    main()
