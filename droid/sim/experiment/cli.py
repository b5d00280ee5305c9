"""droid-experiment: run the seam-tracking experiments of thesis chapter 6 (issue 7).

    droid-experiment run ID|TABLE... [--out DIR] [--realtime] [--seed N] [--jobs N]
                         [--sensor camera|ideal] [--arm fast|full] [--no-figures]
    droid-experiment list [ID|TABLE...]

IDs and tables: droid.sim.experiment.matrix (``droid-experiment list``;
docs/experiments.md).  Lockstep by default, the trials in parallel on a
process pool of ``--jobs`` workers (default: every CPU), longest first, with a
progress bar on stderr.  Per trial: ``DIR/<table>/<id>.csv`` (10 Hz log,
droid.tasks.seam.report.COLUMNS), ``<id>.png`` (unless ``--no-figures``) and
a summary line on stdout.  Per table: ``DIR/<table>/summary.csv`` and
``summary.md`` of the trials of this run; experiment 4 also gets
``std.csv``/``std.png``, the per-s standard deviations across its runs
(§6.2.6).  ``--realtime`` runs each trial, one after the other, on the
real-time process cell (droid.sim.experiment.realtime).

Exit 0 when every trial ran (whatever its tracking outcome), 1 when a trial
could not run, 2 on bad arguments, 130 on SIGINT (the pool is stopped first).
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import signal
import sys
import time
from dataclasses import dataclass, replace
from typing import Sequence

from droid.cli import ArgumentParser, BadInput, non_negative_int, positive_float, positive_int, run
from droid.sim.experiment.matrix import (EXP4_RUNS, POSITION_LABELS, TABLES, Experiment, experiments, resolve,
                                         valid_forms, with_seed)
from droid.sim.experiment.sensors import SENSOR_MODELS
from droid.sim.experiment.trial import ARM_MODELS
from droid.tasks.seam import report
from droid.tasks.seam.core import STOP_END

PROG = "droid-experiment"
DEFAULT_OUT = os.path.join("out", "experiments")
DEFAULT_SEED = 1
#: The sweeps' lead sensor model: "ideal" gives the camera chain's numbers within 0.04 mm
#: RMS on every stable trial of the matrix (docs/experiments.md) at ~3x its speed.
DEFAULT_SENSOR = "ideal"


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog=PROG, description="Run the seam-tracking experiments of thesis chapter 6 "
                                              "(Tables 6.1-6.3, experiments 4 and 5).")
    sub = p.add_subparsers(dest="command", required=True, metavar="{run,list}")
    r = sub.add_parser("run", help="run experiments by ID or table name",
                       description=f"Run experiments. {valid_forms()}.")
    r.add_argument("ids", nargs="+", metavar="ID", help="an ID (1.12), a table (table6.1, exp4) or all")
    r.add_argument("--out", default=DEFAULT_OUT, metavar="DIR", help=f"output directory (default {DEFAULT_OUT})")
    r.add_argument("--realtime", action="store_true", help="run on the real-time process cell (one at a time)")
    r.add_argument("--seed", type=non_negative_int, default=DEFAULT_SEED, metavar="N",
                   help=f"base seed; each trial's seed is derived from it and the ID (default {DEFAULT_SEED})")
    r.add_argument("--jobs", type=positive_int, default=None, metavar="N",
                   help="parallel trials (default: the CPU count)")
    r.add_argument("--sensor", choices=SENSOR_MODELS, default=DEFAULT_SENSOR,
                   help="lead sensor model (default: ideal -- the seam in the field of view with the camera "
                        "chain's noise, ~3x faster; camera: the MVS camera twin and feature code)")
    r.add_argument("--arm", choices=ARM_MODELS, default=None,
                   help="Reis model (default: fast; full runs every Reis core and the plant)")
    r.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    r.add_argument("--record", action="store_true",
                   help="also record each lockstep trial as DIR/<table>/<id>.mcap (docs/observe.md)")
    r.add_argument("--length", type=positive_float, default=None, help=argparse.SUPPRESS)  # run length [mm]
    lp = sub.add_parser("list", help="list the experiments with their parameters, one a line")
    lp.add_argument("ids", nargs="*", metavar="ID", help="IDs or tables to list (default: all)")
    return p


# ---------------------------------------------------------------- one trial (in a worker)

@dataclass(frozen=True)
class Job:
    exp: Experiment
    out_dir: str  # DIR/<table>
    figures: bool
    realtime: bool = False
    record: bool = False  # also write DIR/<table>/<id>.mcap (droid.observe, docs/observe.md)


@dataclass(frozen=True)
class Outcome:
    exp: Experiment
    summary: report.Summary | None
    error: str = ""
    sim_s: float = math.nan
    wall_s: float = math.nan


def run_job(job: Job) -> Outcome:
    """Run one trial and write its CSV (and figure); a trial that cannot start is an Outcome with an error."""
    cfg = job.exp.config
    os.makedirs(job.out_dir, exist_ok=True)
    if job.realtime:
        from droid.sim.experiment.realtime import run_trial_realtime

        result = run_trial_realtime(cfg, job.out_dir)
    else:
        from droid.sim.experiment.trial import run_trial

        try:
            result = run_trial(cfg, record=os.path.join(job.out_dir, job.exp.id + ".mcap") if job.record else None)
        except BadInput as exc:
            return Outcome(job.exp, None, str(exc))
    base = os.path.join(job.out_dir, job.exp.id)
    report.write_csv(base + ".csv", result.rows)
    summary = report.summarize(result.rows, trial_id=job.exp.id, stop_reason=result.stop_reason,
                               stop_detail=result.stop_detail, stop_s_mm=result.stop_s_mm,
                               camera_to_tcp_mm=result.camera_to_tcp_mm)
    if job.figures:
        early = not result.stop_reason.startswith(STOP_END)
        report.figure(base + ".png", result.rows, cfg.title or job.exp.id, cfg.panels,
                      settle_s_mm=summary.settle_s_mm, stop_s_mm=result.stop_s_mm if early else math.nan,
                      stop_label=result.stop_reason if early else "")
    return Outcome(job.exp, summary, sim_s=result.sim_s, wall_s=result.wall_s)


def _worker_init() -> None:
    # Ctrl-C reaches the whole process group: only the parent handles it (and terminates the pool).
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _cost(exp: Experiment) -> float:
    """Relative cost of a trial: its simulated duration (run length / speed) [s]."""
    from droid.sim.workpiece import load_workpiece

    length = exp.config.length_mm or load_workpiece(exp.config.workpiece).length_mm
    return length / exp.config.speed_mm_s


def _progress(total: int):
    from tqdm import tqdm

    return tqdm(total=total, file=sys.stderr, unit="trial", desc=PROG, dynamic_ncols=True, disable=None)


def _emit(line: str) -> None:
    from tqdm import tqdm

    tqdm.write(line, file=sys.stdout)


def run_jobs(jobs: list[Job], workers: int) -> list[Outcome]:
    """Run the jobs (in a pool when workers > 1), printing each summary line as it comes."""
    outcomes: list[Outcome] = []

    def done(o: Outcome) -> None:
        outcomes.append(o)
        if o.summary is not None:
            _emit(report.summary_line(o.summary))
        else:
            print(f"{PROG}: {o.exp.id}: {o.error}", file=sys.stderr)

    if workers <= 1 or len(jobs) == 1:
        with _progress(len(jobs)) as bar:
            for job in jobs:
                done(run_job(job))
                bar.update()
        return outcomes
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else None)
    # Workers ignore SIGINT from their first instruction (inherited at fork; the initializer
    # keeps it so under spawn); the parent turns Ctrl-C into terminating the pool.
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        pool = ctx.Pool(min(workers, len(jobs)), initializer=_worker_init)  # before the bar's monitor thread
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        with _progress(len(jobs)) as bar:
            for o in pool.imap_unordered(run_job, jobs, chunksize=1):
                done(o)
                bar.update()
        pool.close()
    except BaseException:
        pool.terminate()  # SIGINT or an error: stop every worker now
        raise
    finally:
        pool.join()
    return outcomes


# ---------------------------------------------------------------- tables

def table_record(o: Outcome) -> dict:
    e, c = o.exp, o.exp.config
    rec = {"id": e.id, "track": e.track, "speed_mm_s": f"{c.speed_mm_s:g}", "position": c.position,
           "orientation": POSITION_LABELS[c.position], "gains_delay": e.setting, "wrist": c.wrist,
           "seed": c.seed}
    if o.summary is not None:
        rec.update(report.summary_table_row(o.summary))
    else:
        rec.update({k: "" for k in ("rms_lateral_mm", "max_lateral_mm", "rms_depth_mm", "max_depth_mm",
                                    "seam_lost")})
        rec.update(stop_reason=f"error: {o.error}", stop_s_mm="")
    return rec


def write_tables(out: str, outcomes: list[Outcome], figures: bool) -> list[str]:
    """summary.csv/.md per table (trials in matrix order); exp4's std.csv/.png. Returns the files written."""
    order = {eid: i for i, eid in enumerate(experiments())}
    written = []
    for table, title in TABLES.items():
        mine = sorted((o for o in outcomes if o.exp.table == table), key=lambda o: order[o.exp.id])
        if not mine:
            continue
        d = os.path.join(out, table)
        report.write_table(os.path.join(d, "summary.csv"), os.path.join(d, "summary.md"),
                           [table_record(o) for o in mine],
                           title=f"{title} — tool error after settling (s > {mine[0].summary.settle_s_mm:.0f} mm)"
                           if mine[0].summary else title)
        written += [os.path.join(d, "summary.csv"), os.path.join(d, "summary.md")]
        if table == "exp4":
            written += write_exp4_std(d, [o for o in mine if o.summary is not None], figures)
    return written


def write_exp4_std(d: str, outcomes: list[Outcome], figures: bool) -> list[str]:
    """The per-s standard deviation across the experiment-4 runs of this invocation (Figures 6.31-6.32)."""
    if len(outcomes) < 2:
        print(f"{PROG}: exp4: {len(outcomes)} run(s), need 2 or more for the standard deviations "
              f"(run all {EXP4_RUNS}: exp4)", file=sys.stderr)
        return []
    runs = [report.read_csv(os.path.join(d, o.exp.id + ".csv")) for o in outcomes]
    try:
        grid, stds = report.std_across_runs(runs)
    except ValueError as exc:
        print(f"{PROG}: exp4: no standard deviations: {exc}", file=sys.stderr)
        return []
    files = [os.path.join(d, "std.csv")]
    report.write_std_csv(files[0], grid, stds)
    if figures:
        files.append(os.path.join(d, "std.png"))
        ids = ", ".join(o.exp.id for o in outcomes)
        report.std_figure(files[1], grid, stds, f"Experiment 4: standard deviation across runs {ids}")
    return files


# ---------------------------------------------------------------- main

def cmd_list(names: Sequence[str]) -> int:
    for e in resolve(names or ["all"]):
        print(e.describe())
    return 0


def cmd_run(args) -> int:
    picked = [with_seed(e, args.seed) for e in resolve(args.ids)]
    overrides = {}
    if args.sensor:
        overrides["sensor"] = args.sensor
    if args.arm:
        overrides["arm"] = args.arm
    if args.length:
        overrides["length_mm"] = args.length
    if overrides:
        picked = [replace(e, config=replace(e.config, **overrides)) for e in picked]
    figures = not args.no_figures
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"--out {args.out}: {exc.strerror}") from None
    jobs = [Job(e, os.path.join(args.out, e.table), figures, args.realtime, args.record) for e in picked]
    workers = 1 if args.realtime else (args.jobs or os.cpu_count() or 1)
    if workers > 1:
        jobs.sort(key=lambda j: -_cost(j.exp))  # longest first: the pool ends together
    t0 = time.perf_counter()
    outcomes = run_jobs(jobs, workers)
    files = write_tables(args.out, outcomes, figures)
    wall = time.perf_counter() - t0
    failed = [o.exp.id for o in outcomes if o.summary is None]
    sim = sum(o.sim_s for o in outcomes if o.summary is not None)
    print(f"{PROG}: {len(outcomes)} trial(s), {sim:.0f} s simulated in {wall:.1f} s wall on {workers} worker(s); "
          f"tables: {', '.join(f for f in files if f.endswith('summary.md')) or 'none'}", file=sys.stderr)
    if failed:
        print(f"{PROG}: {len(failed)} trial(s) could not run: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


@run
def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "list":
        return cmd_list(args.ids)
    return cmd_run(args)


if __name__ == "__main__":
    sys.exit(main())
