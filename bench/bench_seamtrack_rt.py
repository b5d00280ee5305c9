#!/usr/bin/env python3
"""The README's seam-tracking trial in real time beside the same trial in lockstep (issue 12).

Brings up a copy of the built-in simulated cell under a unique name, homes both arms,
runs ``droid-seamtrack SPEED --mode MODE --start i --length LENGTH --log ...`` (the
README's main job: 16 mm/s, plus mode, 400 mm) ``--runs`` times, brings the cell down,
then runs the same trial in lockstep (``TrialConfig(position="i", arm="full",
sensor="camera", holder="gmf1", mode=MODE)``) for ``--seeds`` seeds.  Both are summarised
by the same ``droid.tasks.seam.report.summarize`` (tool-tip sensor, after settling):
lateral / depth RMS and max, travel speed.  Prints figures, decides nothing; the load
average is printed beside them (the trial's accuracy, not a latency, so no cyclictest
floor applies).

Usage: bench/bench_seamtrack_rt.py [--speed 16] [--mode plus] [--length 400] [--runs 1] [--seeds 3]
"""
from __future__ import annotations

import sys
import tempfile
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.floor import when_and_load  # noqa: E402
from bench.live_cell import droid_module as droid, renamed_cell, up_and_homed  # noqa: E402
from droid.brain.cell.cellfile import builtin_cell_path  # noqa: E402
from droid.cli import ArgumentParser, bounded_float, bounded_int  # noqa: E402
from droid.tasks.seam.report import read_csv, summarize  # noqa: E402


def fmt(label: str, s) -> str:
    return (f"{label:<28} lateral RMS {s.rms_lateral_mm:.3f} max {s.max_lateral_mm:.3f} mm, depth RMS "
            f"{s.rms_depth_mm:.3f} max {s.max_depth_mm:.3f} mm, speed {s.travel_speed_mm_s:.2f} mm/s, "
            f"end s {s.end_s_mm:.1f} mm, {s.stop_reason or '-'}")


# Alike in shape only to other benches' mains: its own options, its own figures.
def main() -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speed", type=bounded_float(0.1, 200.0, "mm/s"), default=16.0, help="commanded speed [mm/s]")
    ap.add_argument("--mode", choices=("plus", "thesis", "listing"), default="plus")
    ap.add_argument("--length", type=bounded_float(160.0, 700.0, "mm"), default=400.0, help="run length [mm]")
    ap.add_argument("--runs", type=bounded_int(0, 20, "runs"), default=1, help="real-time runs")
    ap.add_argument("--seeds", type=bounded_int(0, 20, "seeds"), default=3, help="lockstep seeds (1..N)")
    args = ap.parse_args()
    print(when_and_load(), flush=True)
    rt = []
    if args.runs:
        with tempfile.TemporaryDirectory(prefix="droid-rt-") as tmp:
            name = "b" + uuid.uuid4().hex[:9]
            text = builtin_cell_path().read_text()
            text = renamed_cell(text, name, f"{tmp}/run")
            cell = Path(tmp) / "cell.toml"
            cell.write_text(text)
            try:
                failed = up_and_homed(cell)
                if failed:
                    print(failed, flush=True)
                    return 1
                for i in range(args.runs):
                    log = Path(tmp) / f"rt{i}.csv"
                    out = droid("droid.tasks.seamtrack", f"{args.speed:g}", "--mode", args.mode, "--start", "i",
                                "--length", f"{args.length:g}", "--log", str(log), "--cell", str(cell),
                                timeout=120 + 3 * args.length / args.speed)
                    print(f"real time run {i + 1}: exit {out.returncode}: {out.stdout.strip().splitlines()[:1]}",
                          flush=True)
                    if log.exists():
                        s = summarize(read_csv(log), trial_id=f"rt{i}", commanded_mm_s=args.speed)
                        rt.append(s)
                        print(fmt(f"  real time {i + 1}", s), flush=True)
            finally:
                droid("droid.brain.runtime.launcher", "down", "--cell", str(cell))
    from droid.experiments.trial import TrialConfig, run_trial

    ls = []
    for seed in range(1, args.seeds + 1):
        r = run_trial(TrialConfig("rt-vs-ls", "i", args.speed, length_mm=args.length, seed=seed, mode=args.mode))
        s = summarize(r.rows, trial_id=f"ls{seed}", stop_reason=r.stop_reason, stop_s_mm=r.stop_s_mm,
                      camera_to_tcp_mm=r.camera_to_tcp_mm, commanded_mm_s=args.speed)
        ls.append(s)
        print(fmt(f"lockstep seed {seed}", s), flush=True)
    if rt and ls:
        rt_lat = np.mean([s.rms_lateral_mm for s in rt])
        ls_lat = np.mean([s.rms_lateral_mm for s in ls])
        print(f"lateral RMS: real time {rt_lat:.3f} mm (mean of {len(rt)}), lockstep {ls_lat:.3f} mm "
              f"(mean of {len(ls)} seeds, SD {np.std([s.rms_lateral_mm for s in ls]):.3f}); "
              f"difference {rt_lat - ls_lat:+.3f} mm", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
