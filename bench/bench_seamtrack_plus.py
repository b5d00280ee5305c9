"""Thesis mode beside plus mode: the tracking targets of issue 12 (lockstep, figures not verdicts).

Lockstep trials (droid.experiments.trial.run_trial) with the ``camera`` lead
sensor chain (the camera twin's render with 0.5 px stripe jitter and 2 %
spurious rows, the real MVS feature extraction, the serial line) and the
experiments' default arm model (``full`` since issue 13: every Reis core and the
plant twin, homed before each trial; ``--arm fast`` for the analytic one), N seeds
each, both modes:

* ``r200_64``: the R200 ramp (position vii) at 64 mm/s -- lateral RMS / max,
  steady depth error (|mean tool depth| after settling);
* ``step_V`` (V = 4, 16, 32, 64, 128 mm/s): the step track (position i) over
  ``--step-length`` mm -- seam lost or not, lateral max (the 5 degree corner
  at 100 mm);
* ``r25_16``: an R25 arc (the bundled workpiece ``ramp_r25``, 20 mm
  surfaces) at 16 mm/s -- tracked to its end or not;
* ``delay16``: the step track at 16 mm/s with a 16-cycle transport delay at
  150 mm (§6.2.5) against the same trial without: the lateral RMS ratio;
* every trial: the achieved travel speed after settling / the commanded one.

Prints one markdown table of mean +- SD over the seeds (and ``--json``).
Usage: PYTHONPATH=. python bench/bench_seamtrack_plus.py [--seeds 20] [--modes thesis,plus]
[--speeds 4,16,32,64,128] [--step-length 400] [--arm full|fast] [--jobs N] [--json]
"""
from __future__ import annotations

import json
import math
import os
import platform
import time

import numpy as np

from droid.cli import ArgumentParser, BadInput, bounded_float, bounded_int, run
from droid.experiments.trial import ARM_MODELS, TrialConfig, run_trial
from droid.tasks.seam.params import MAX_RUN_LENGTH_MM, MODES
from droid.tasks.seam.report import column, summarize


def _one(job: tuple) -> dict:
    mode, seed, kw = job
    return one(mode, seed, **kw)


def one(mode: str, seed: int, **kw) -> dict:
    r = run_trial(TrialConfig("bench", mode=mode, seed=seed, sensor="camera", **kw))
    su = summarize(r.rows, stop_reason=r.stop_reason, camera_to_tcp_mm=r.camera_to_tcp_mm,
                   commanded_mm_s=kw["speed_mm_s"])
    s = column(r.rows, "s_mm")
    dep = column(r.rows, "tool_depth_mm")[np.isfinite(s) & (s > su.settle_s_mm)]
    return {"rms_lat": su.rms_lateral_mm, "max_lat": su.max_lateral_mm, "rms_dep": su.rms_depth_mm,
            "steady_dep": abs(float(np.nanmean(dep))) if dep.size else math.nan,
            "speed_ratio": su.travel_speed_mm_s / kw["speed_mm_s"], "lost": float(su.seam_lost),
            "end": su.stop_reason, "wall_s": r.wall_s}


def trials(speeds, step_length):
    yield "r200_64", dict(position="vii", workpiece="ramp_r200", speed_mm_s=64.0)
    yield "r25_16", dict(position="vii", workpiece="ramp_r25", speed_mm_s=16.0)
    for v in speeds:
        yield f"step_{v:g}", dict(position="i", speed_mm_s=float(v), length_mm=step_length)
    yield "nodelay16", dict(position="i", speed_mm_s=16.0, length_mm=step_length)
    yield "delay16", dict(position="i", speed_mm_s=16.0, length_mm=step_length, delay_cycles=16, delay_at_mm=150.0)


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog="bench_seamtrack_plus", description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=bounded_int(1, 1000, "seeds"), default=20, help="seeds per trial (default 20)")
    p.add_argument("--modes", default="thesis,plus", help="modes to compare (default thesis,plus)")
    p.add_argument("--speeds", default="4,16,32,64,128", help="step-track speeds [mm/s]")
    p.add_argument("--step-length", type=bounded_float(0.0, MAX_RUN_LENGTH_MM, "mm", lo_open=True), default=400.0,
                   help="step-track run length [mm]")
    p.add_argument("--trials", default=None, help="only these trials (comma-separated names, e.g. r25_16)")
    p.add_argument("--arm", choices=ARM_MODELS, default=TrialConfig.arm, help="Reis model (default: full)")
    p.add_argument("--jobs", type=bounded_int(1, 256, "processes"), default=1,
                   help="processes to run the trials on (default 1)")
    p.add_argument("--json", action="store_true", help="also print the raw figures as JSON")
    return p


def fmt(v: np.ndarray, digits: int = 3) -> str:
    v = v[np.isfinite(v)]
    if not v.size:
        return "n/a"
    return f"{v.mean():.{digits}f} ± {v.std(ddof=1) if v.size > 1 else 0.0:.{digits}f}"


@run
def main(argv=None) -> int:
    a = build_parser().parse_args(argv)
    modes = [m for m in a.modes.split(",") if m]
    for m in modes:
        if m not in MODES:
            raise BadInput(f"--modes: unknown mode {m!r} (known: {', '.join(MODES)})")
    try:
        speeds = [float(x) for x in a.speeds.split(",") if x]
    except ValueError:
        raise BadInput(f"--speeds: not a list of numbers: {a.speeds!r}") from None
    if not speeds or any(not (v > 0 and math.isfinite(v)) for v in speeds):
        raise BadInput("--speeds: every speed must be > 0 mm/s")
    t0 = time.perf_counter()
    res: dict = {}
    only = None if a.trials is None else set(a.trials.split(","))
    names = [n for n, _ in trials(speeds, a.step_length) if only is None or n in only]
    if not names:
        raise BadInput(f"--trials: none of {a.trials!r} is a trial of this bench")
    jobs = [((name, m), (m, seed, dict(kw, arm=a.arm))) for name, kw in trials(speeds, a.step_length)
            if name in names for m in modes for seed in range(1, a.seeds + 1)]
    if a.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(a.jobs) as pool:
            out = list(pool.map(_one, [j for _, j in jobs]))
    else:
        out = [_one(j) for _, j in jobs]
    for (key, _), r in zip(jobs, out):
        res.setdefault(key, []).append(r)
    wall = time.perf_counter() - t0
    print(f"# bench_seamtrack_plus: {a.seeds} seeds, arm {a.arm}, {a.jobs} process(es), {platform.node()} ({os.cpu_count()} CPUs), "
          f"load {os.getloadavg()[0]:.2f}, {time.strftime('%Y-%m-%d %H:%M')} , {wall:.0f} s wall")
    print()
    print("| trial | mode | lateral RMS [mm] | lateral max [mm] | steady depth [mm] | speed / commanded "
          "| seam lost | ends |")
    print("|---|---|---|---|---|---|---|---|")
    for name in names:
        for m in modes:
            rs = res[(name, m)]
            col = {k: np.array([r[k] for r in rs], float) for k in ("rms_lat", "max_lat", "steady_dep",
                                                                       "speed_ratio", "lost")}
            ends = sorted({r["end"] for r in rs})
            print(f"| {name} | {m} | {fmt(col['rms_lat'])} | {fmt(col['max_lat'])} | {fmt(col['steady_dep'])} "
                  f"| {fmt(col['speed_ratio'])} | {int(col['lost'].sum())}/{len(rs)} | {', '.join(ends)} |")
    for m in modes if {"nodelay16", "delay16"} <= set(names) else ():
        base = np.array([r["rms_lat"] for r in res[("nodelay16", m)]])
        dl = np.array([r["rms_lat"] for r in res[("delay16", m)]])
        print(f"\n{m}: a 16-cycle transport delay at 150 mm changes the lateral RMS by "
              f"{fmt(100.0 * (dl / base - 1.0), 1)} %")
    if a.json:
        print(json.dumps({f"{k[0]}/{k[1]}": v for k, v in res.items()}, default=float))
    return 0


if __name__ == "__main__":
    main()
