"""Lockstep seam-tracking trials: simulated seconds per wall second (thesis §6.1 trials).

Runs one whole-seam trial (droid.experiments.trial.run_trial, the default
``full`` arm model, or ``--arm fast``) per configuration -- tool speeds 4, 16 and
64 mm/s, start positions i, iii and vii (vii on its ramp workpiece), the ``camera`` lead sensor
(render + the real MVS feature extraction) and the ``ideal`` one (closed
form + noise) -- and prints per trial: simulated seconds, wall seconds,
speed-up (simulated / wall), the stop reason and the RMS tool-tip errors
after s = 150 mm.  With the full arm each trial first homes the arm and moves it
to the start (``prep_s`` simulated seconds, in the wall time too): the speed-up is
printed for the trial alone (the tracking run's simulated seconds / the whole wall
time), for everything simulated (``all_x``: prep + trial) and per CPU second of the
trial's process (``cpu_x``, prep + trial: on a shared machine the better estimate of an
idle one's).  ``--stages`` also times the stages (camera render, MVS feature extraction,
lead sensor in all, arm model, tracking core, tool-tip
sensor; the "arm" stage is the fast model's -- the full model runs on the
scheduler) by wrapping them; the wrappers cost a little, so the speed-ups of a
``--stages`` run are slightly lower.  ``--jobs N`` runs the trials on N
processes (the matrix figure: total simulated seconds per wall second).

Timing is measured here, never in tests: the machine is shared, so the
figures depend on its load (see docs/benchmarks.md).  Usage:
PYTHONPATH=. python bench/bench_seamtrack.py [--speeds 4,16,64] [--positions i,iii,vii] [--arm fast|full]
[--sensors camera,ideal] [--seed N] [--stages] [--jobs N] [--json]
"""
from __future__ import annotations

import json
import math
import os
import platform
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from droid.cli import ArgumentParser, BadInput, bounded_int, run, seed_int
from droid.experiments import trial
from droid.sim.mvs import trial_sensors as sensors
from droid.sim.reis import fast_arm as arm_fast
from droid.sim.mvs.camera import MvsCamera
from droid.subunits.mvs.sensor import SensorCore
from droid.tasks.seam.core import SeamTracker
from droid.brain.cell.cell_layout import load_layout

STAGES = (("render", MvsCamera, "frame"), ("feature", SensorCore, "step"), ("lead sensor", sensors.LeadSensor, "read"),
          ("arm", arm_fast.FastArm, "tick"), ("core", SeamTracker, "step"), ("tool sensor", trial, "tool_reading"))
AFTER_MM = 150.0  # RMS errors past the initial section and the step input (as tests/sim)


def _install_stage_timers(acc: dict) -> None:
    """Wrap each stage's function to add its wall time [s] to ``acc`` (this process only)."""
    clock = time.perf_counter
    for name, owner, attr in STAGES:
        fn = getattr(owner, attr)

        def timed(*a, _fn=fn, _name=name, **kw):
            t0 = clock()
            try:
                return _fn(*a, **kw)
            finally:
                acc[_name] += clock() - t0
        setattr(owner, attr, timed)


def _workpiece(position: str) -> str:
    return load_layout().position(position).workpiece or "step_input"


def one_trial(job: tuple) -> dict:
    """Run one configuration (position, speed [mm/s], sensor, seed, stages?) and return its figures."""
    position, speed, sensor, seed, stages, arm = job
    acc: dict = defaultdict(float)
    if stages:
        _install_stage_timers(acc)
    cfg = trial.TrialConfig(f"{position}-{speed:g}-{sensor}", position, speed, workpiece=_workpiece(position),
                            sensor=sensor, seed=seed, arm=arm)
    cpu0 = time.process_time()
    r = trial.run_trial(cfg)
    cpu = time.process_time() - cpu0
    s = r.column("s_mm")
    after = s > AFTER_MM
    lat, dep = r.column("tool_lateral_mm")[after], r.column("tool_depth_mm")[after]
    rms = (lambda v: float(np.sqrt(np.nanmean(v ** 2))) if np.isfinite(v).any() else math.nan)
    return {"position": position, "speed_mm_s": speed, "sensor": sensor, "seed": seed, "arm": arm,
            "sim_s": round(r.sim_s, 3), "prep_s": round(r.prep_s, 3), "wall_s": round(r.wall_s, 4),
            "speedup_x": round(r.speedup, 1), "all_x": round((r.sim_s + r.prep_s) / r.wall_s, 1),
            "cpu_s": round(cpu, 3), "cpu_x": round((r.sim_s + r.prep_s) / cpu, 1) if cpu > 0 else math.inf,
            "stop": r.stop_reason, "rms_lateral_mm": round(rms(lat), 4), "rms_depth_mm": round(rms(dep), 5),
            "stages_s": {k: round(v, 4) for k, v in acc.items()}}


def _csv(text: str, kind, what: str) -> list:
    try:
        return [kind(v) for v in text.split(",") if v]
    except ValueError:
        raise BadInput(f"--{what}: expected a comma-separated list, got {text!r}") from None


@run
def main(argv=None) -> int:
    parser = ArgumentParser(prog="bench_seamtrack", description=__doc__.split("\n")[0])
    parser.add_argument("--speeds", default="4,16,64", help="tool speeds [mm/s], comma-separated")
    parser.add_argument("--positions", default="i,iii,vii", help="start positions, comma-separated")
    parser.add_argument("--sensors", default="camera,ideal", help="lead sensor models, comma-separated")
    parser.add_argument("--seed", type=seed_int, default=1, help="random seed")
    parser.add_argument("--arm", choices=trial.ARM_MODELS, default="full",
                        help="Reis model: fast (analytic servo) or full (every core + the Pinocchio plant)")
    parser.add_argument("--stages", action="store_true", help="time the stages too (slightly slower)")
    parser.add_argument("--jobs", type=bounded_int(1, 256, "processes"), default=1,
                        help="processes to run the trials on")
    parser.add_argument("--json", action="store_true", help="one JSON object a trial, then a summary")
    args = parser.parse_args(argv)
    jobs = [(p, v, s, args.seed, args.stages, args.arm) for s in _csv(args.sensors, str, "sensors")
            for p in _csv(args.positions, str, "positions") for v in _csv(args.speeds, float, "speeds")]
    for p in {j[0] for j in jobs}:
        load_layout().position(p)  # a bad position fails before any trial runs
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(one_trial, jobs))
    else:
        results = [one_trial(j) for j in jobs]
    wall = time.perf_counter() - t0
    sim = sum(r["sim_s"] + r["prep_s"] for r in results)
    summary = {"machine": f"{platform.node()} {platform.machine()} Python {platform.python_version()}, "
                          f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}",
               "trials": len(results), "jobs": args.jobs, "sim_s": round(sim, 1), "wall_s": round(wall, 2),
               "speedup_x": round(sim / wall, 1)}
    if args.json:
        for r in results:
            print(json.dumps(r))
        print(json.dumps(summary))
        return 0
    print(f"machine {summary['machine']}")
    head = f"{'position':>8} {'mm/s':>5} {'sensor':>6} {'prep s':>6} {'sim s':>7} {'wall s':>7} {'speed-up':>8} " \
           f"{'all':>7} {'all/cpu':>7}  " \
           f"{'stop':<12} {'rms lat mm':>10} {'rms dep mm':>10}"
    if args.stages:
        head += "  stage shares of wall time"
    print(head)
    for r in results:
        line = (f"{r['position']:>8} {r['speed_mm_s']:>5g} {r['sensor']:>6} {r['prep_s']:>6.1f} {r['sim_s']:>7.1f} "
                f"{r['wall_s']:>7.3f} {r['speedup_x']:>7.1f}x {r['all_x']:>6.1f}x {r['cpu_x']:>6.1f}x  {r['stop']:<12} {r['rms_lateral_mm']:>10.3f} {r['rms_depth_mm']:>10.4f}")
        if args.stages:
            line += "  " + ", ".join(f"{k} {100 * v / r['wall_s']:.0f}%" for k, v in r["stages_s"].items())
        print(line)
    print(f"all {summary['trials']} trials: {summary['sim_s']} s simulated (prep + trials) in {summary['wall_s']} s wall on "
          f"{args.jobs} process(es): {summary['speedup_x']}x real time")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
