#!/usr/bin/env python3
"""droid-contact on the real-time cell: force holding, F/T latency, over-force stop (issue 27).

Brings up a copy of the built-in simulated cell under a unique name, homes both arms, and
measures, printing figures (it decides nothing):

1. **force holding**: ``droid-contact arm1 --start i --force 20 --speed 10 --length 200``
   ``--runs`` times; its summary line (normal-force RMS error and max after settling);
2. **F/T record to Brain Status**: for ``--seconds`` with the arm at rest, every new F/T
   record in the Brain's Status (polled at ~2 kHz in this process) against the time it
   arrived at droid-ft (``sample_ns``, CLOCK_MONOTONIC): p50 / p99 / max [ms] and p99 in
   heartbeat periods (target p99 <= 2);
3. **over-force stop**: the arm moved over the plate (droid-move), 1 s at rest (the F/T's rest
   reading; once droid-contact biases the sensor, the reading inside its tare window after the
   bias), then ``droid-contact arm1 --gains G`` with ``touch_n`` above ``force_max_n``: it
   presses until the over-force stop -- droid-ft's guard on arm1 (FAULT_FORCE) or the task's.  From the first F/T record past the limit (the tared
   normal force, ``sample_ns``) to standstill (the arm's encoders within 2 counts from then on
   for 200 ms) [ms] (target <= 50 ms), and the over-force reading seen by the task.

Then the machine's floor (cyclictest, bench/floor.py) measured in the same run, and the load.

Usage: bench/bench_contact_rt.py [--runs 1] [--seconds 20] [--overforce 3]
"""
from __future__ import annotations

import os
import re
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

from bench.floor import cyclictest_floor  # noqa: E402
from droid.brain.cellfile import builtin_cell_path, load_cell  # noqa: E402
from droid.brain.databases import open_brain  # noqa: E402
from droid.cli import ArgumentParser, bounded_int  # noqa: E402
from droid.kinematics.transforms import T_to_pose  # noqa: E402
from droid.tasks.contact.prog import ContactRun, build_parser  # noqa: E402

FORCE_MAX_N = 40.0


def droid(mod: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", mod, *args], capture_output=True, text=True, timeout=timeout,
                          cwd=ROOT)


class Sampler(threading.Thread):
    """Polls the Brain's F/T and arm Status: new F/T records (seen_ns, sample_ns, force_tool_N)
    and the arm's encoders (t_ns, encoder_pos)."""

    def __init__(self, cell) -> None:
        super().__init__(daemon=True)
        self.ft = open_brain(cell, cell.subunit("ft"), "status")
        self.ft_cmd = open_brain(cell, cell.subunit("ft"), "command")
        self.arm = open_brain(cell, cell.subunit("arm1"), "status")
        self.bias_ns: int | None = None  # when the task wrote its bias command (droid-contact's tare)
        self.records: list[tuple[int, int, np.ndarray]] = []
        self.encoders: list[tuple[int, np.ndarray]] = []
        self.stop = threading.Event()

    def run(self) -> None:
        last = None
        bias0 = int(self.ft_cmd.read()["bias_id"])
        while not self.stop.is_set():
            if self.bias_ns is None and int(self.ft_cmd.read()["bias_id"]) != bias0:
                self.bias_ns = time.monotonic_ns()
            f = self.ft.read()
            now = time.monotonic_ns()
            seq = int(f["rdt_seq"])
            if seq != last and int(f["valid"]):
                last = seq
                self.records.append((now, int(f["sample_ns"]), np.asarray(f["force_tool_N"], float).copy()))
            a = self.arm.read()
            self.encoders.append((time.monotonic_ns(), np.asarray(a["encoder_pos"], np.int64).copy()))
            time.sleep(0.0005)

    def close(self) -> None:
        self.stop.set()
        self.join(2.0)
        self.ft.close()
        self.ft_cmd.close()
        self.arm.close()


def latency(cell, seconds: float, period_ms: float) -> str:
    s = Sampler(cell)
    s.start()
    time.sleep(seconds)
    s.close()
    lat = np.array([(seen - sample) / 1e6 for seen, sample, _ in s.records[1:]])
    if not len(lat):
        return "F/T -> Brain Status: no records seen"
    p50, p99, mx = np.percentile(lat, 50), np.percentile(lat, 99), lat.max()
    return (f"F/T record -> Brain Status over {seconds:g} s ({len(lat)} records seen): p50 {p50:.1f} ms, "
            f"p99 {p99:.1f} ms ({p99 / period_ms:.2f} heartbeat periods), max {mx:.1f} ms")


def overforce(cell_path: Path, cell, tmp: Path, k: int) -> str:
    args = build_parser().parse_args(["arm1", "--start", "i", "--cell", str(cell_path)])
    T_arm, T_hold = ContactRun(args, cell).start_pose("i")
    for arm, T in (("gmf1", T_hold), ("arm1", T_arm)):
        out = droid("droid.tasks.move", arm, "--cell", str(cell_path), "cart", "--",
                    *(f"{v:.4f}" for v in T_to_pose(T)), "4", timeout=120)
        if out.returncode != 0:
            return f"over-force run {k}: droid-move {arm} failed: {out.stderr.strip()}"
    time.sleep(1.0)  # the servo settles
    s = Sampler(cell)
    s.start()
    time.sleep(1.0)  # the rest reading
    gains = tmp / "press.toml"
    gains.write_text(f"touch_n = {FORCE_MAX_N + 5:g}\nforce_max_n = {FORCE_MAX_N:g}\n")
    out = droid("droid.tasks.contact.prog", "arm1", "--force", "20", "--gains", str(gains), "--quiet",
                "--cell", str(cell_path), timeout=120)
    time.sleep(0.5)
    s.close()
    if "over-force" not in out.stderr:
        return f"over-force run {k}: no over-force stop: {out.stderr.strip()}"
    if s.bias_ns is not None:  # the task biased the sensor: the reference is read after that,
        # inside its 0.5 s tare window (the bias lands within ~0.15 s; the approach follows the tare)
        t_rest_end = s.bias_ns + 0.5e9
        rest = np.median([f[0] for seen, _, f in s.records if s.bias_ns + 0.2e9 <= seen < t_rest_end])
    else:
        t_rest_end = s.records[0][0] + 0.9e9
        rest = np.median([f[0] for seen, _, f in s.records if seen < t_rest_end])
    cross = next(((sample, rest - f[0]) for seen, sample, f in s.records
                  if seen >= t_rest_end and rest - f[0] > FORCE_MAX_N), None)
    if cross is None:
        return f"over-force run {k}: the F/T stream never crossed {FORCE_MAX_N:g} N"
    t_cross, f_cross = cross
    enc = [(t, p) for t, p in s.encoders if t >= t_cross]
    still = None
    for i, (t, p) in enumerate(enc):
        later = [q for u, q in enc[i:] if u <= t + 200e6]
        if enc[-1][0] < t + 200e6:
            break
        if all(np.max(np.abs(q - p)) <= 2 for q in later):
            still = t
            break
    m = re.search(r"normal force ([0-9.]+) N", out.stderr)
    seen = m.group(1) if m else "?"
    if still is None:
        return f"over-force run {k}: no standstill within the record"
    return (f"over-force run {k}: crossing {FORCE_MAX_N:g} N (first record {f_cross:.1f} N) -> standstill "
            f"{(still - t_cross) / 1e6:.0f} ms; the task stopped at {seen} N")


def main() -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=bounded_int(0, 20, "runs"), default=1, help="force-holding runs")
    ap.add_argument("--seconds", type=bounded_int(1, 600, "s"), default=20, help="latency window [s]")
    ap.add_argument("--overforce", type=bounded_int(0, 20, "runs"), default=3, help="over-force runs")
    args = ap.parse_args()
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}, {os.cpu_count()} CPUs", flush=True)
    with tempfile.TemporaryDirectory(prefix="droid-contact-") as tmpd:
        tmp = Path(tmpd)
        name = "b" + uuid.uuid4().hex[:9]
        text = builtin_cell_path().read_text()
        text = re.sub(r'(?m)^name = "[^"]*"', f'name = "{name}"\nrun_dir = "{tmp}/run"', text, count=1)
        cell_path = tmp / "cell.toml"
        cell_path.write_text(text)
        cell = load_cell(str(cell_path))
        up = droid("droid.brain.launcher", "up", "--cell", str(cell_path), timeout=180)
        try:
            if up.returncode != 0:
                print("cell did not come up:", up.stderr.strip().splitlines()[-1:], flush=True)
                return 1
            for arm in ("arm1", "gmf1"):
                out = droid("droid.tasks.home", arm, "--cell", str(cell_path), timeout=200)
                if out.returncode != 0:
                    print(f"droid-home {arm} failed: {out.stderr.strip()}", flush=True)
                    return 1
            for i in range(args.runs):
                out = droid("droid.tasks.contact.prog", "arm1", "--start", "i", "--force", "20", "--speed", "10",
                            "--length", "200", "--quiet", "--log", str(tmp / f"run{i}.csv"), "--cell",
                            str(cell_path), timeout=300)
                print(f"run {i}: exit {out.returncode}: {out.stdout.strip().splitlines()[0] if out.stdout else ''}"
                      f"{'' if out.returncode == 0 else ' | ' + out.stderr.strip()}", flush=True)
            print(latency(cell, args.seconds, 1e3 / cell.heartbeat_hz), flush=True)
            for k in range(args.overforce):
                print(overforce(cell_path, cell, tmp, k), flush=True)
        finally:
            droid("droid.brain.launcher", "down", "--cell", str(cell_path), timeout=120)
    print(cyclictest_floor(5.0), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
