"""Each program's memory and CPU in a running cell, idle and while it tracks a seam (issue 28).

Brings up a copy of a cell file (default: the built-in simulated cell) under a unique
name, lets it settle, then samples every program ``droid-cell status --json`` lists:

- resident (Rss) and proportional (Pss) memory from ``/proc/PID/smaps_rollup`` [MB],
  and the locked part (``Locked``) [MB];
- CPU as a share of one core over the sampling window (utime + stime from
  ``/proc/PID/stat``) [%].

Two windows: the idle cell (after ``droid-home`` of both arms), and a plus-mode seam-tracking
run (``droid-seamtrack 16 --mode plus --start i --length LEN``), sampled from the moment the
tracker is running.  It prints one row per program and the sums, then brings the cell down.
Memory is not a timing figure, but CPU is: the load average is printed beside it.

    .venv/bin/python bench/bench_footprint.py [--cell FILE] [--idle-s 10] [--length 200] [--no-track]
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.live_cell import droid_program as droid, renamed_cell  # noqa: E402
from droid.brain.cell.cellfile import builtin_cell_path, load_cell  # noqa: E402
from droid.cli import ArgumentParser, bounded_float  # noqa: E402

TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def make_cell(tmp: Path, source: Path) -> Path:
    name = f"fp{uuid.uuid4().hex[:6]}"
    path = tmp / f"{name}.toml"
    path.write_text(renamed_cell(source.read_text(), name, f"{tmp}/run"))
    return path


def programs(cell: Path) -> dict[str, int]:
    """name -> pid of every live program of the cell."""
    out = droid(cell, "droid-cell", "status", "--json").stdout
    rows = [json.loads(x) for x in out.splitlines() if x.strip()]
    return {r["name"]: int(r["pid"]) for r in rows if r.get("alive") and r.get("pid")}


def memory_mb(pid: int) -> dict[str, float]:
    """Rss, Pss and Locked of one process [MB] (smaps_rollup, kB in the file)."""
    got = {}
    with open(f"/proc/{pid}/smaps_rollup") as f:
        for line in f:
            key, _, rest = line.partition(":")
            if key in ("Rss", "Pss", "Locked"):
                got[key] = int(rest.split()[0]) / 1024.0
    return got


def cpu_ticks(pid: int) -> int:
    """utime + stime of one process [clock ticks]."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])


def cpu_snapshot(pids: dict[str, int]) -> dict[str, int]:
    """name -> utime + stime [clock ticks] of every program still alive."""
    got = {}
    for name, pid in pids.items():
        try:
            got[name] = cpu_ticks(pid)
        except OSError:
            pass
    return got


def cpu_window(pids: dict[str, int], seconds: float) -> dict[str, float]:
    """name -> CPU [% of one core] over the next ``seconds`` of every program alive throughout."""
    t0 = time.monotonic()
    c0 = cpu_snapshot(pids)
    time.sleep(seconds)
    dt = time.monotonic() - t0
    c1 = cpu_snapshot(pids)
    return {name: (c1[name] - c0[name]) / TICKS_PER_S / dt * 100.0 for name in c0 if name in c1}


def sample(pids: dict[str, int], seconds: float) -> dict[str, dict[str, float]]:
    """Memory at the end and CPU [% of one core] over ``seconds`` of every program still alive."""
    rows = {}
    for name, cpu in cpu_window(pids, seconds).items():
        try:
            rows[name] = {"cpu_pct": cpu, **memory_mb(pids[name])}
        except OSError:
            continue
    return rows


def show(title: str, rows: dict[str, dict[str, float]]) -> None:
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"\n== {title} (load average {load}) ==")
    print(f"{'program':32s} {'Rss MB':>8s} {'Pss MB':>8s} {'Locked MB':>10s} {'CPU %':>7s}")
    for name in sorted(rows):
        r = rows[name]
        print(f"{name:32s} {r['Rss']:8.1f} {r['Pss']:8.1f} {r.get('Locked', 0.0):10.1f} {r['cpu_pct']:7.1f}")
    tot = {k: sum(r.get(k, 0.0) for r in rows.values()) for k in ("Rss", "Pss", "Locked", "cpu_pct")}
    print(f"{'sum (' + str(len(rows)) + ' programs)':32s} {tot['Rss']:8.1f} {tot['Pss']:8.1f} "
          f"{tot['Locked']:10.1f} {tot['cpu_pct']:7.1f}")
    biggest = max(rows.items(), key=lambda kv: kv[1]["Rss"])
    print(f"largest resident: {biggest[0]} {biggest[1]['Rss']:.1f} MB")


def main() -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cell", type=Path, default=builtin_cell_path(), help="cell file to copy (default: built-in)")
    ap.add_argument("--idle-s", type=bounded_float(1.0, 600.0), default=10.0, help="idle window [s]")
    ap.add_argument("--length", type=bounded_float(50.0, 400.0), default=200.0, help="seam length tracked [mm]")
    ap.add_argument("--no-track", action="store_true", help="measure the idle cell only")
    args = ap.parse_args()
    print(f"bench_footprint: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}, {os.cpu_count()} CPUs, "
          f"DROID_NO_MLOCK={os.environ.get('DROID_NO_MLOCK', '')!r}")
    with tempfile.TemporaryDirectory(prefix="droid-fp.") as tmp:
        cell = make_cell(Path(tmp), args.cell)
        up = droid(cell, "droid-cell", "up")
        if up.returncode != 0:
            print(f"droid-cell up failed: {up.stderr.strip()}", file=sys.stderr)
            droid(cell, "droid-cell", "down")
            return 1
        try:
            for arm in [n for n, sub in load_cell(cell).subunits.items() if sub.cls == "arm6r"]:
                h = droid(cell, "droid-home", arm)
                if h.returncode != 0:
                    print(f"droid-home {arm} failed: {h.stderr.strip()}", file=sys.stderr)
                    return 1
            time.sleep(2.0)
            show("idle cell (homed)", sample(programs(cell), args.idle_s))
            if not args.no_track:
                exe = Path(sys.executable).parent / "droid-seamtrack"
                track = subprocess.Popen([str(exe), "16", "--mode", "plus", "--start", "i",
                                          "--length", f"{args.length:g}", "--cell", str(cell),
                                          "--log", f"{tmp}/track.csv"],
                                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                time.sleep(8.0)  # the move to the start position
                pids = programs(cell)
                pids["droid-seamtrack"] = track.pid
                rows = sample(pids, min(args.idle_s, args.length / 16.0 * 0.6))
                out, err = track.communicate(timeout=600)
                show("tracking (plus mode, 16 mm/s)", rows)
                print(f"droid-seamtrack exit {track.returncode}: {(out or err).strip().splitlines()[-1:]}")
        finally:
            droid(cell, "droid-cell", "down")
    return 0


if __name__ == "__main__":
    sys.exit(main())
