#!/usr/bin/env python3
"""Real time on a busy host (issue 16): prints figures, decides nothing.

A cell of its own (a copy of the built-in simulated cell under a unique name) is
brought up while the host carries background load:

* ``--busy N`` processes spinning at normal priority (default 4: two per core here),
* ``--memory-mb M`` of memory touched over and over (page-cache and TLB pressure),
* ``--io`` a writer that fsyncs 1 MiB files in a loop.

Then ``--rounds R`` rounds, each: ``droid-home arm1``; ``--moves K`` joint moves to
random targets (1-3 s, within +-4000 counts of home) with the arrival error read
from the Brain's Status afterwards; optionally (``--seamtrack``) one seam-tracking
trial.  Every failure is printed with the program's own reason.

Beside the cell's figures it prints the *machine's floor* measured in the same run
and under the same load: ``cyclictest`` (Debian's rt-tests, SCHED_FIFO, 60 Hz and
500 Hz threads) — installed by ``scripts/rt-tests.sh`` when missing.  Heartbeat
lateness is measured by a subscriber from the ticks' own send times; the servo's
and the heartbeat's overruns come from ``droid-cell status --json``.  Lateness is
reported as a ratio to the floor's figure of the same percentile.

Usage: bench/bench_under_load.py [--busy 4] [--rounds 10] [--moves 5] [--no-fifo]
                                 [--memory-mb 512] [--io] [--seamtrack]
Record the printed block with the date in docs/benchmarks.md.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import platform
import random
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.live_cell import droid_program, renamed_cell  # noqa: E402
from droid.brain.cell.cellfile import builtin_cell_path, load_cell  # noqa: E402
from droid.brain.plumbing import wire  # noqa: E402
from droid.cli import ArgumentParser, bounded_int, duration_s, seed_int  # noqa: E402


# -- background load ------------------------------------------------------------
def _spin(stop) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(10000):
            x += 1


def _memory(stop, mb: int) -> None:
    buf = np.zeros(mb * 1024 * 1024 // 8)
    while not stop.is_set():
        buf += 1.0  # touches every page


def _io(stop, folder: str) -> None:
    block = os.urandom(1 << 20)
    i = 0
    while not stop.is_set():
        p = os.path.join(folder, f"io{i % 4}.bin")
        with open(p, "wb") as f:
            f.write(block)
            f.flush()
            os.fsync(f.fileno())
        i += 1


class Load:
    def __init__(self, busy: int, memory_mb: int, io: bool, folder: str) -> None:
        ctx = mp.get_context("fork")
        self.stop = ctx.Event()
        self.procs = [ctx.Process(target=_spin, args=(self.stop,), daemon=True) for _ in range(busy)]
        if memory_mb:
            self.procs.append(ctx.Process(target=_memory, args=(self.stop, memory_mb), daemon=True))
        if io:
            self.procs.append(ctx.Process(target=_io, args=(self.stop, folder), daemon=True))

    def __enter__(self):
        for p in self.procs:
            p.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        for p in self.procs:
            p.join(5)
            if p.is_alive():
                p.kill()


# -- the machine's floor -------------------------------------------------------
def cyclictest(seconds: float) -> dict | None:
    """cyclictest's per-thread histograms [us] -> percentiles, or None when absent."""
    exe = shutil.which("cyclictest")
    if exe is None:
        return None
    with tempfile.TemporaryDirectory() as d:
        hist = os.path.join(d, "hist")
        # one SCHED_FIFO 80 thread at 60 Hz (16667 us), one at 500 Hz (2000 us), side by side
        procs = {}
        for name, interval in (("60Hz", 16667), ("500Hz", 2000)):
            cmd = [exe, "-q", "-m", "-p", "80", "-t", "1", "-i", str(interval), "-D", f"{int(seconds)}",
                   "-h", "20000", f"--histfile={hist}.{name}"]
            procs[name] = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        out = {}
        for name, p in procs.items():
            if p.wait() != 0 or not os.path.exists(f"{hist}.{name}"):
                continue
            counts: dict[int, int] = {}
            for line in Path(f"{hist}.{name}").read_text().splitlines():
                if line.startswith("#") or not line.strip():
                    continue
                us, n = (int(x) for x in line.split()[:2])
                if n:
                    counts[us] = n
            vals = np.repeat(np.fromiter(counts.keys(), float), np.fromiter(counts.values(), int))
            if vals.size:
                out[name] = {"p50": float(np.percentile(vals, 50)), "p99": float(np.percentile(vals, 99)),
                             "max": float(vals.max()), "n": int(vals.size)}
    return out


# -- the cell ------------------------------------------------------------------
def make_cell(tmp: Path, fifo: bool, source: Path | None = None) -> Path:
    """A renamed copy of ``source`` (default: the built-in simulated cell) with its run dir in
    ``tmp`` and ``sched_fifo`` as asked."""
    name = f"load{uuid.uuid4().hex[:6]}"
    text = renamed_cell((source or builtin_cell_path()).read_text(), name, f"{tmp}/run")
    text = re.sub(r"(?m)^sched_fifo = \w+", f"sched_fifo = {'true' if fifo else 'false'}", text, count=1)
    p = tmp / f"{name}.toml"
    p.write_text(text)
    return p


def droid(cell: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """A droid console script on ``cell`` (two minutes at the most unless told)."""
    return droid_program(cell, *args, timeout=timeout)


def status_json(cell: Path) -> dict[str, dict]:
    r = droid(cell, "droid-cell", "status", "--json")
    return {o["name"]: o for o in (json.loads(x) for x in r.stdout.splitlines() if x.strip())}


class TickLateness(threading.Thread):
    """Subscribes to the heartbeat; lateness of tick n = t_ns(n) - (earliest t_ns(k) - k*period)."""

    def __init__(self, endpoint: str) -> None:
        super().__init__(daemon=True)
        import zmq
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self.sock.setsockopt(zmq.RCVTIMEO, 200)
        self.sock.connect(endpoint)
        self.samples: list[tuple[int, int, int]] = []
        self.halt = threading.Event()

    def run(self) -> None:
        import zmq
        while not self.halt.is_set():
            try:
                frame = self.sock.recv()
            except zmq.Again:
                continue
            try:
                t = wire.unpack_tick(frame)
            except wire.BadFrame:
                continue
            self.samples.append((t.tick, t.t_ns, t.period_ns))

    def stop(self) -> dict:
        self.halt.set()
        self.join(2)
        self.sock.close(0)
        self.ctx.term()
        if len(self.samples) < 10:
            return {}
        ticks = np.array([s[0] for s in self.samples], float)
        t_ns = np.array([s[1] for s in self.samples], float)
        period = self.samples[-1][2]
        phase = t_ns - ticks * period
        late_us = (phase - phase.min()) / 1e3
        gaps = np.diff(ticks)
        return {"p50": float(np.percentile(late_us, 50)), "p99": float(np.percentile(late_us, 99)),
                "max": float(late_us.max()), "n": len(late_us), "missed": int(np.sum(gaps[gaps > 1] - 1))}


def arrival_error_counts(cell: Path, target) -> float | None:
    r = droid(cell, "droid-snoop", "arm1", "--json", "--count", "1")
    try:
        rec = json.loads(r.stdout.splitlines()[0])
        pos = np.asarray(rec["encoder_pos"], float)
    except (IndexError, KeyError, ValueError):
        return None
    return float(np.max(np.abs(pos - np.asarray(target, float))))


def reason(r: subprocess.CompletedProcess) -> str:
    lines = [x for x in (r.stderr or "").splitlines() if x.strip()]
    return lines[-1] if lines else f"exit {r.returncode}"


def main() -> int:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--busy", type=bounded_int(0, 256, "processes"), default=4,
                    help="busy processes at normal priority")
    ap.add_argument("--memory-mb", type=bounded_int(0, 1 << 20, "MiB"), default=0, help="memory kept busy [MiB]")
    ap.add_argument("--io", action="store_true", help="an fsync-ing writer")
    ap.add_argument("--rounds", type=bounded_int(0, 10_000, "rounds"), default=10, help="rounds of homing + moves")
    ap.add_argument("--moves", type=bounded_int(0, 10_000, "moves"), default=5, help="joint moves per round")
    ap.add_argument("--no-fifo", action="store_true", help="the cell without SCHED_FIFO")
    ap.add_argument("--seamtrack", action="store_true", help="a seam-tracking trial per round")
    ap.add_argument("--floor-seconds", type=duration_s(), default=20.0, help="cyclictest run [s]")
    ap.add_argument("--seed", type=seed_int, default=1, help="random seed")
    ap.add_argument("--cell", type=Path, default=None,
                    help="cell file to copy (default: the built-in simulated cell; it needs arm1 and gmf1)")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    fifo = not args.no_fifo
    print(f"bench_under_load: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}  {platform.node()}  "
          f"{os.cpu_count()} cpu  python {platform.python_version()}  load avg {os.getloadavg()[0]:.1f}")
    print(f"  load: {args.busy} busy, {args.memory_mb} MiB memory, io={'yes' if args.io else 'no'};  "
          f"cell sched_fifo={fifo}, {args.cell or 'the built-in cell'}")
    results = {"home": [0, 0], "move": [0, 0], "seam": [0, 0]}
    failures: list[str] = []
    arrival: list[float] = []
    seam_rms: list[float] = []
    with tempfile.TemporaryDirectory(prefix="droid-load-") as tmpd:
        tmp = Path(tmpd)
        cell = make_cell(tmp, fifo, args.cell)
        with Load(args.busy, args.memory_mb, args.io, tmpd):
            floor: dict = {}
            ft = threading.Thread(target=lambda: floor.update(cyclictest(args.floor_seconds) or {}))
            ft.start()
            up = droid(cell, "droid-cell", "up")
            if up.returncode != 0:
                print(f"  cell did not come up: {reason(up)}")
                droid(cell, "droid-cell", "down")
                ft.join()
                return 1
            try:
                hb = TickLateness(load_cell(cell).heartbeat)
                hb.start()
                before = status_json(cell)
                t0 = time.monotonic()
                for rnd in range(args.rounds):
                    r = droid(cell, "droid-home", "arm1")
                    results["home"][0 if r.returncode == 0 else 1] += 1
                    if r.returncode:
                        failures.append(f"round {rnd} home: {reason(r)}")
                        continue
                    for _ in range(args.moves):
                        tgt = [rng.randint(-4000, 4000) for _ in range(6)]
                        secs = rng.uniform(1.0, 3.0)
                        r = droid(cell, "droid-move", "arm1", "joint", *map(str, tgt), f"{secs:.2f}")
                        results["move"][0 if r.returncode == 0 else 1] += 1
                        if r.returncode:
                            failures.append(f"round {rnd} move: {reason(r)}")
                        else:
                            err = arrival_error_counts(cell, tgt)
                            if err is not None:
                                arrival.append(err)
                    if args.seamtrack:
                        r = droid(cell, "droid-home", "gmf1")
                        # past the summary's settling window (s > 150 mm), as the README's trial
                        r = droid(cell, "droid-seamtrack", "16", "--start", "i", "--length", "300", timeout=300) \
                            if r.returncode == 0 else r
                        results["seam"][0 if r.returncode == 0 else 1] += 1
                        m = re.search(r"tool lateral RMS ([0-9.]+) mm", r.stdout)
                        if r.returncode:
                            failures.append(f"round {rnd} seamtrack: {reason(r)}")
                        elif m:
                            seam_rms.append(float(m.group(1)))
                elapsed = time.monotonic() - t0
                after = status_json(cell)
                lat = hb.stop()
            finally:
                down = droid(cell, "droid-cell", "down")
                if down.returncode:
                    print(f"  droid-cell down: {reason(down)}")
                notes = []
                for log in sorted((tmp / "run" / "logs").glob("*.log")):
                    notes += [x for x in log.read_text(errors="replace").splitlines()
                              if "slipped" in x or " fault " in x or "overruns (" in x]
            ft.join()
    print(f"  rounds {args.rounds} in {elapsed:.0f} s")
    for k, (ok, bad) in results.items():
        if ok or bad:
            print(f"  {k:<10} {ok} ok, {bad} failed")
    if arrival:
        print(f"  arrival error (max joint) median {np.median(arrival):.0f} counts, max {max(arrival):.0f} counts")
    if seam_rms:
        print(f"  seam tracking lateral RMS: {', '.join(f'{v:.2f}' for v in seam_rms)} mm")
    for name in ("droid-heartbeat", "droid-servo arm1", "droid-watchdog arm1", "droid-servo-agent arm1"):
        b, a = before.get(name), after.get(name)
        if b and a:
            print(f"  {name:<24} cycles {a['cycles'] - b['cycles']:>7}  overruns {a['overruns'] - b['overruns']}")
    f60 = floor.get("60Hz")
    if lat:
        print(f"  heartbeat lateness   p50 {lat['p50']:7.0f} us  p99 {lat['p99']:7.0f} us  max {lat['max']:7.0f} us"
              f"  missed {lat['missed']} of {lat['n']}")
    for name, f in floor.items():
        print(f"  floor cyclictest {name:<5} p50 {f['p50']:7.0f} us  p99 {f['p99']:7.0f} us  max {f['max']:7.0f} us"
              f"  (n={f['n']})")
    if lat and f60:
        print(f"  heartbeat / floor    p99 {lat['p99'] / max(f60['p99'], 1.0):.1f}x   max {lat['max'] / max(f60['max'], 1.0):.1f}x")
    if not floor:
        print("  floor: cyclictest unavailable (scripts/rt-tests.sh installs Debian's rt-tests)")
    for n in notes:
        print(f"  log: {n}")
    for f in failures:
        print(f"  FAIL {f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
