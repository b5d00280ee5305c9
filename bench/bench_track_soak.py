"""A long tracking soak: the default cell tracks seams back to back for ``--minutes`` beside two
CPU-bound normal-priority processes, then every program's own lateness record (issue 40's
"in a 10-minute tracking soak beside two busy processes, no real-time program late by 20 ms or
more").

Brings up a copy of a cell file (default: the built-in simulated cell) under a unique name,
homes both arms, starts the two busy processes of bench/bench_demo_soak.py (a lockstep
``droid-experiment run table6.1`` loop and ``python -c "while 1: pass"``; ``--quiet`` leaves
them out), reads every program's worst wake-up lateness so far (``lateness_max_ms`` of
``droid-cell status --json``), then runs ``droid-seamtrack 16 --mode plus --start i --length
LEN`` again and again until the minutes are up, each run's summary on a line.  At the end:
the lateness records again, per program with its scheduler, and which of them rose during the
soak; the runs that passed (exit 0, lateral RMS <= 0.12 mm at 16.0 mm/s); droid-sim's own count
of its wake-ups over the cell's life (its log at exit); and the machine's floor (cyclictest)
before and after.  The kernel logs only its first RT throttling of a boot, so the programs' own
records are the evidence.  A bench script: timing never decides a test.

    .venv/bin/python bench/bench_track_soak.py [--minutes 10] [--length 400] [--quiet]
"""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_demo_soak import MAX_RMS_MM, SPEED_MM_S, busy, judged, stop  # noqa: E402
from bench.bench_footprint import make_cell  # noqa: E402
from bench.floor import cyclictest_floor  # noqa: E402
from bench.live_cell import droid_program as droid, up_and_homed  # noqa: E402
from droid.brain.cell.cellfile import builtin_cell_path  # noqa: E402
from droid.cli import ArgumentParser, bounded_float  # noqa: E402

LATE_MS = 20.0  # the "late by 20 ms or more"


def records(cell: Path) -> dict[str, tuple[str, float | None]]:
    """name -> (scheduler, worst wake-up lateness so far [ms]) of every live program."""
    out = droid(cell, "droid-cell", "status", "--json").stdout
    rows = [json.loads(x) for x in out.splitlines() if x.strip()]
    return {r["name"]: (r.get("sched") or "?", r.get("lateness_max_ms")) for r in rows if r.get("alive")}


def track(cell: Path, k: int, length_mm: float, keep: Path | None) -> bool:
    t0 = time.monotonic()
    log = [] if keep is None else ["--log", str(keep / f"run{k + 1}.csv")]
    run = droid(cell, "droid-seamtrack", "16", "--mode", "plus", "--start", "i", "--length", f"{length_mm:g}",
                *log, timeout=600)
    ok, what = judged(run.returncode, run.stdout + run.stderr)
    print(f"run {k + 1}: exit {run.returncode} in {time.monotonic() - t0:.0f} s: {'ok' if ok else 'FAILED'}: "
          f"{what}", flush=True)
    if keep is not None and (keep / f"run{k + 1}.csv").exists():
        for row in glitches(keep / f"run{k + 1}.csv"):
            print(f"  {row}", flush=True)
    return ok


def glitches(path: Path, over_mm: float = 0.5) -> list[str]:
    """The rows of a tracking log whose tool-tip lateral or depth error is beyond ``over_mm``
    [mm], with the arm's travel since the row before (a row every 0.1 s: 1.6 mm at 16 mm/s)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    out, prev = [], None
    for r in rows:
        s = float(r["s_mm"])
        lat, dep = float(r["tool_lateral_mm"]), float(r["tool_depth_mm"])
        if prev is not None and (abs(lat) > over_mm or abs(dep) > over_mm):
            out.append(f"glitch at s {s:.1f} mm (t {float(r['t_s']):.2f} s, travel since last row "
                       f"{s - prev:.2f} mm): tool lateral {lat:+.2f} depth {dep:+.2f} mm")
        prev = s
    return out


def rose(before: dict, after: dict) -> str:
    """The programs whose worst-lateness record rose between two readings: "name a->b ms, ..."."""
    out = []
    for name, (_, lt) in sorted(after.items(), key=lambda kv: -(kv[1][1] or 0.0)):
        b = before.get(name, ("?", None))[1]
        if lt is not None and (b is None or lt > b):
            out.append(f"{name} {0.0 if b is None else b:.1f}->{lt:.1f}")
    return ", ".join(out) or "none"


def new_lines(logs: Path, seen: dict[Path, int], words=("took", "stalled", "slipped", "LAGGING")) -> list[str]:
    """The cell's log lines written since the last call that name a stall (droid-sim's slow
    steps, a slipped clock), each with its program's log name."""
    found = []
    for log in sorted(logs.glob("*.log")):
        lines = log.read_text(errors="replace").splitlines()
        for ln in lines[seen.get(log, 0):]:
            if any(w in ln for w in words):
                found.append(f"{log.stem}: {ln}")
        seen[log] = len(lines)
    return found


def show(before: dict, after: dict) -> int:
    """The lateness table; returns how many real-time programs were 20 ms late or more."""
    print(f"\n{'program':30s} {'sched':>6s} {'worst late before [ms]':>23s} {'after [ms]':>11s}")
    late = 0
    for name in sorted(after, key=lambda n: -(after[n][1] or 0.0)):
        sched, lt = after[name]
        b = before.get(name, ("?", None))[1]
        rose = "  (rose during the soak)" if lt is not None and b is not None and lt > b else ""
        fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
        print(f"{name:30s} {sched:>6s} {fmt(b):>23s} {fmt(lt):>11s}{rose}")
        if sched == "fifo" and lt is not None and lt >= LATE_MS:
            late += 1
    return late


def main() -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cell", type=Path, default=builtin_cell_path(), help="cell file to copy (default: built-in)")
    ap.add_argument("--minutes", type=bounded_float(0.5, 240.0), default=10.0, help="soak length [min]")
    ap.add_argument("--length", type=bounded_float(50.0, 400.0), default=400.0, help="seam length a run [mm]")
    ap.add_argument("--quiet", action="store_true", help="without the two busy processes")
    ap.add_argument("--keep", type=Path, help="keep each run's tracking log (runN.csv) in this folder")
    args = ap.parse_args()
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    print(f"bench_track_soak: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}, {os.cpu_count()} CPUs, "
          f"{args.minutes:g} min {'quiet' if args.quiet else 'beside two busy processes'}", flush=True)
    print(f"before: {cyclictest_floor(3.0, 1000)}", flush=True)
    passed = runs = 0
    with tempfile.TemporaryDirectory(prefix="droid-tsoak.") as tmp:
        cell = make_cell(Path(tmp), args.cell)
        extra: list[subprocess.Popen] = []
        try:
            err = up_and_homed(cell)
            if err:
                print(err, file=sys.stderr)
                return 1
            extra = [] if args.quiet else busy(tmp, [])
            time.sleep(3.0)
            before = records(cell)
            end = time.monotonic() + args.minutes * 60.0
            seen: dict[Path, int] = {}
            new_lines(Path(tmp) / "run" / "logs", seen)
            last = before
            while time.monotonic() < end:
                passed += track(cell, runs, args.length, args.keep)
                runs += 1
                now = records(cell)  # which records rose in this run, and what the cell logged
                print(f"  late records that rose: {rose(last, now)}", flush=True)
                for ln in new_lines(Path(tmp) / "run" / "logs", seen):
                    print(f"  {ln}", flush=True)
                last = now
            after = records(cell)
            load = " ".join(f"{v:.2f}" for v in os.getloadavg())
        finally:
            stop(extra)
            droid(cell, "droid-cell", "down")
        late = show(before, after)
        for log in sorted(Path(tmp).glob("**/logs/*sim*.log")):
            lines = [ln for ln in log.read_text(errors="replace").splitlines() if "wake-ups:" in ln]
            print(f"{log.name}: {lines[-1] if lines else 'no step-time summary'}")
    print(f"after: {cyclictest_floor(3.0, 1000)}")
    print(f"{passed} of {runs} tracking runs passed (lateral RMS <= {MAX_RMS_MM} mm at {SPEED_MM_S} mm/s); "
          f"{late} real-time program(s) {LATE_MS:g} ms late or more; load average at the end {load}")
    return 0 if passed == runs and late == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
