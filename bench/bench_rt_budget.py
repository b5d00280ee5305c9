"""The cell's real-time budget, measured per program: CPU share, scheduler and worst lateness while
the default cell homes, idles, tracks a seam and presses (issue 40 item 1).

Brings up a copy of a cell file (default: the built-in simulated cell) under a unique name and
samples every program ``droid-cell status --json`` lists over four windows:

- homing: while ``droid-home ARM`` runs for the first arm (the Reis searches its switches);
- idle: the homed cell, nothing commanded (``--idle-s``);
- tracking: ``droid-seamtrack 16 --mode plus --start i --length LEN``, from the moment it tracks;
- pressing: ``droid-contact ARM --ft FT --start i --force 20 --speed 10 --length LEN``, likewise, for
  the cell's first force/torque sensor (class ft6) and its ``guard_arm`` (skipped without one).

Per program: its share of one core over the window (utime + stime from ``/proc/PID/stat``) [%],
the scheduler it runs on (fifo / nice / other) and, at the end, its loop's worst wake-up lateness
so far (``lateness_max_ms`` of droid-cell status) [ms], with the machine's floor (cyclictest,
bench/floor.py) measured before and after the cell in the same run; at the end, droid-sim's own
count of its wake-ups over the cell's life (its log: step time p50/p99/max, wake-ups 20 ms late).  Per window: the sum over the programs,
the SCHED_FIFO part of it and that part per CPU of this process's affinity -- the figure the
kernel's RT throttling and droid-cell up's real-time budget (RT_BUDGET_PCT_PER_CPU) are about --
beside the programs' declared shares (droid.brain.runtime.launcher.demand).  The load average is printed
with each window: CPU is a timing figure.  Timing is measured here, never in tests.

    .venv/bin/python bench/bench_rt_budget.py [--cell FILE] [--idle-s 10] [--length 200] [--force]
    taskset -c 0 .venv/bin/python bench/bench_rt_budget.py --force   # the cell on one CPU
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_footprint import cpu_window, make_cell, programs  # noqa: E402
from bench.floor import cyclictest_floor  # noqa: E402
from bench.live_cell import droid_program as droid  # noqa: E402
from droid.brain.cell.cellfile import builtin_cell_path, load_cell  # noqa: E402
from droid.brain.runtime.launcher import RT_BUDGET_PCT_PER_CPU, cell_programs, demand, measured_cpu  # noqa: E402
from droid.cli import ArgumentParser, bounded_float  # noqa: E402


def window(pids: dict[str, int], seconds: float) -> dict[str, dict]:
    """CPU [% of one core] over ``seconds`` and the scheduler of every program still alive."""
    return {name: {"cpu_pct": cpu, "sched": measured_cpu(pids[name])[0] or "?"}
            for name, cpu in cpu_window(pids, seconds).items()}


def lateness(cell: Path) -> dict[str, float | None]:
    out = droid(cell, "droid-cell", "status", "--json").stdout
    return {r["name"]: r.get("lateness_max_ms") for r in (json.loads(x) for x in out.splitlines() if x.strip())}


def show(title: str, rows: dict[str, dict], late: dict[str, float | None], cpus: int) -> dict:
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"\n== {title} (load average {load}) ==")
    print(f"{'program':30s} {'sched':>6s} {'CPU %':>7s} {'worst late ms':>14s}")
    for name in sorted(rows, key=lambda n: -rows[n]["cpu_pct"]):
        r = rows[name]
        lt = late.get(name)
        print(f"{name:30s} {r['sched']:>6s} {r['cpu_pct']:7.1f} {'-' if lt is None else f'{lt:.2f}':>14s}")
    total = sum(r["cpu_pct"] for r in rows.values())
    fifo = sum(r["cpu_pct"] for r in rows.values() if r["sched"] == "fifo")
    print(f"sum {total:.1f} % of one core; SCHED_FIFO {fifo:.1f} % = {fifo / cpus:.1f} % a CPU over {cpus} "
          f"CPU(s) (budget {RT_BUDGET_PCT_PER_CPU:.0f} % a CPU)")
    return {"window": title, "sum_pct": round(total, 1), "fifo_pct": round(fifo, 1),
            "fifo_pct_per_cpu": round(fifo / cpus, 1)}


def task(cell: Path, tmp: str, argv: list[str], settle_s: float, seconds: float, cpus: int, title: str) -> dict:
    exe = Path(sys.executable).parent / argv[0]
    proc = subprocess.Popen([str(exe), *argv[1:], "--cell", str(cell)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(settle_s)  # the approach moves
    pids = programs(cell)
    pids[argv[0]] = proc.pid
    rows = window(pids, seconds)
    out, err = proc.communicate(timeout=600)
    got = show(title, rows, lateness(cell), cpus)
    last = (out or err).strip().splitlines()[-1:] if (out or err).strip() else []
    print(f"{argv[0]} exit {proc.returncode}: {last}")
    got["exit"] = proc.returncode
    return got


def pressing_pair(cell) -> tuple[str, str] | None:
    """(arm, F/T sensor) for the pressing window: the first ft6 subunit whose guard_arm is an arm
    of the cell; None if there is none (the ABB weld cell has no F/T sensor)."""
    for name, sub in cell.subunits.items():
        arm = sub.options.get("guard_arm")
        if sub.cls == "ft6" and arm in cell.subunits and cell.subunits[arm].cls == "arm6r":
            return arm, name
    return None


def main() -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cell", type=Path, default=builtin_cell_path(), help="cell file to copy (default: built-in)")
    ap.add_argument("--idle-s", type=bounded_float(1.0, 600.0), default=10.0, help="idle window [s]")
    ap.add_argument("--length", type=bounded_float(50.0, 400.0), default=200.0, help="seam/slide length [mm]")
    ap.add_argument("--force", action="store_true", help="droid-cell up --force (a cell over the budget)")
    ap.add_argument("--json", action="store_true", help="also one JSON line of the window sums")
    args = ap.parse_args()
    cpus = len(os.sched_getaffinity(0))
    print(f"bench_rt_budget: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}, {os.cpu_count()} CPUs, "
          f"affinity {sorted(os.sched_getaffinity(0))}")
    print(f"before: {cyclictest_floor(3.0, 1000)}", flush=True)
    sums = []
    with tempfile.TemporaryDirectory(prefix="droid-rt.") as tmp:
        cell = make_cell(Path(tmp), args.cell)
        c = load_cell(cell)
        first, rest = cell_programs(c, None)
        need = demand(c, first + rest)
        print(f"declared: {need.cpu_pct:.0f} % of one core, SCHED_FIFO {need.fifo_pct:.0f} % = "
              f"{need.fifo_pct_per_cpu:.0f} % a CPU over {need.cpus} CPU(s)")
        up = droid(cell, "droid-cell", "up", *(["--force"] if args.force else []))
        if up.returncode != 0:
            print(f"droid-cell up failed: {up.stderr.strip()}", file=sys.stderr)
            droid(cell, "droid-cell", "down")
            return 1
        try:
            arms = [n for n, sub in c.subunits.items() if sub.cls == "arm6r"]
            exe = Path(sys.executable).parent / "droid-home"
            home = subprocess.Popen([str(exe), arms[0], "--cell", str(cell)], stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            time.sleep(2.0)
            rows = window(programs(cell) | {"droid-home": home.pid}, 12.0)
            _, err = home.communicate(timeout=300)
            sums.append(show(f"homing {arms[0]}", rows, lateness(cell), cpus))
            if home.returncode != 0:
                print(f"droid-home {arms[0]} failed: {err.strip()}", file=sys.stderr)
                return 1
            for arm in arms[1:]:
                h = droid(cell, "droid-home", arm)
                if h.returncode != 0:
                    print(f"droid-home {arm} failed: {h.stderr.strip()}", file=sys.stderr)
                    return 1
            time.sleep(2.0)
            sums.append(show("idle (homed)", window(programs(cell), args.idle_s), lateness(cell), cpus))
            seconds = min(args.idle_s, args.length / 16.0 * 0.6)
            sums.append(task(cell, tmp, ["droid-seamtrack", "16", "--mode", "plus", "--start", "i",
                                         "--length", f"{args.length:g}"], 8.0, seconds, cpus,
                             "tracking (plus mode, 16 mm/s)"))
            press = pressing_pair(c)
            if press is None:
                print("pressing: skipped: the cell has no force/torque sensor (class ft6) with a guard_arm")
            else:
                arm, ft = press
                sums.append(task(cell, tmp, ["droid-contact", arm, "--ft", ft, "--start", "i", "--force", "20",
                                             "--speed", "10", "--length", f"{min(args.length, 200.0):g}"], 10.0,
                                 min(args.idle_s, min(args.length, 200.0) / 10.0 * 0.5), cpus,
                                 f"pressing {arm} (20 N, 10 mm/s)"))
        finally:
            droid(cell, "droid-cell", "down")
            for log in sorted(Path(tmp).glob("**/logs/*sim*.log")):  # droid-sim's wake-ups, its whole life
                lines = [ln for ln in log.read_text(errors="replace").splitlines() if "wake-ups:" in ln]
                print(f"{log.name}: {lines[-1] if lines else 'no step-time summary'}")
    print(f"after: {cyclictest_floor(3.0, 1000)}")
    if args.json:
        print(json.dumps(sums))
    return 0


if __name__ == "__main__":
    sys.exit(main())
