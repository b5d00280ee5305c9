"""droid-experiment: run the seam-tracking experiments of thesis chapter 6 (issue 7), and sweep plans (issue 15).

    droid-experiment run ID|TABLE... [--out DIR] [--realtime] [--seed N] [--jobs N]
                         [--sensor camera|ideal] [--arm fast|full] [--mode thesis|listing|plus]
                         [--cell FILE] [--no-figures] [--dask ADDRESS]
    droid-experiment run --plan FILE.toml [--out DIR] [--resume] [--jobs N] [--no-figures] [--dask ADDRESS]
    droid-experiment list [ID|TABLE...]
    droid-experiment list --plan FILE.toml

A plan (droid.experiments.plan) is a researcher's own sweep: its trials
write ``DIR/<plan name>/<id>.csv``, ``.png``, ``.json`` (the trial's
parameters and summary: its results exist) and one tidy ``results.csv`` (a
row per trial, in plan order: the parameters and the summary figures).  A
plan with ``trial = "contact"`` sweeps the lockstep force-control trial
instead (droid.experiments.contact_trial, thesis §7.3): its CSVs have
contact_trial.COLUMNS, its figures and ``results.csv``/``results.md``
come from droid.experiments.contact_report.
``--resume`` skips trials whose ``.json`` exists.  ``--dask ADDRESS`` runs
the trials on a Dask distributed cluster (``tcp://host:8786``, or ``local``
for a LocalCluster of ``--jobs`` workers) instead of the process pool; the
workers compute, this process writes every file.

IDs and tables: droid.experiments.matrix (``droid-experiment list``;
docs/experiments.md).  Lockstep by default, the trials in parallel on a
process pool of ``--jobs`` workers (default: every CPU), longest first, with a
progress bar on stderr.  Per trial: ``DIR/<table>/<id>.csv`` (10 Hz log,
droid.tasks.seam.report.COLUMNS), ``<id>.png`` (unless ``--no-figures``) and
a summary line on stdout.  Per table: ``DIR/<table>/summary.csv`` and
``summary.md`` of the trials of this run; experiment 4 also gets
``std.csv``/``std.png``, the per-s standard deviations across its runs
(§6.2.6).  ``--realtime`` runs each trial, one after the other, on the
real-time process cell (droid.experiments.realtime).  ``--cell FILE`` runs the
lockstep trials on that cell file: its layout, welder and holder
(droid.sim.trial_cell; not with ``--realtime``).

Exit 0 when every trial ran (whatever its tracking outcome), 1 when a trial
could not run (or the Dask scheduler does not answer), 2 on bad arguments or a
bad plan, 130 on SIGINT (the pool is stopped first).
"""
from __future__ import annotations

import argparse
import csv
import functools
import json
import math
import os
import re
import sys
import time
from dataclasses import replace
from typing import Sequence

from droid.cli import ArgumentParser, BadInput, bounded_float, bounded_int, run
from droid.experiments import phases
from droid.experiments.jobs import NO_MATPLOTLIB, Job, Outcome, is_contact, json_safe, run_and_store, run_job, store
from droid.experiments.matrix import EXP4_RUNS, POSITION_LABELS, TABLES, experiments, resolve, valid_forms, with_seed
from droid.experiments.plan import FIELDS, TRIAL_CONTACT, Plan, PlanTrial, load_plan
from droid.experiments.trial import ARM_MODELS, SENSOR_MODELS
from droid.tasks.seam import report
from droid.tasks.seam.params import MAX_RUN_LENGTH_MM, MODES

PROG = "droid-experiment"
DEFAULT_OUT = os.path.join("out", "experiments")
DEFAULT_SEED = 1
#: Most parallel trials --jobs accepts (each is a process; the CPU count is the default).
MAX_JOBS = 256
#: The sweeps' lead sensor model: "ideal" gives the camera chain's numbers within 0.04 mm
#: RMS on every stable trial of the matrix (docs/experiments.md) at ~3x its speed.
DEFAULT_SENSOR = "ideal"


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog=PROG, description="Run the seam-tracking experiments of thesis chapter 6 "
                                              "(Tables 6.1-6.3, experiments 4 and 5).")
    sub = p.add_subparsers(dest="command", required=True, metavar="{run,list}")
    r = sub.add_parser("run", help="run experiments by ID or table name, or a sweep plan",
                       description=f"Run experiments. {valid_forms()}; or --plan FILE.toml.")
    r.add_argument("ids", nargs="*", metavar="ID", help="an ID (1.12), a table (table6.1, exp4) or all")
    r.add_argument("--plan", metavar="FILE", help="a sweep plan (TOML; or a bundled plan's name)")
    r.add_argument("--resume", action="store_true", help="with --plan: skip trials whose results exist")
    r.add_argument("--dask", metavar="ADDRESS",
                   help="run the trials on a Dask cluster: tcp://HOST:8786, or local (a LocalCluster)")
    r.add_argument("--out", default=DEFAULT_OUT, metavar="DIR", help=f"output directory (default {DEFAULT_OUT})")
    r.add_argument("--realtime", action="store_true", help="run on the real-time process cell (one at a time)")
    r.add_argument("--seed", type=bounded_int(0, 2**31 - 1), default=None, metavar="N",
                   help=f"base seed; each trial's seed is derived from it and the ID (default {DEFAULT_SEED})")
    r.add_argument("--jobs", type=bounded_int(1, MAX_JOBS, "processes"), default=None, metavar="N",
                   help="parallel trials (default: the CPU count)")
    r.add_argument("--sensor", choices=SENSOR_MODELS, default=None,
                   help="lead sensor model (default: ideal -- the seam in the field of view with the camera "
                        "chain's noise, ~3x faster; camera: the MVS camera twin and feature code)")
    r.add_argument("--arm", choices=ARM_MODELS, default=None,
                   help="arm model (default: full -- every core of the welder's subunit and its twin, homed before "
                        "each trial; fast: the Reis's planner and one second-order loop per joint, ~10x faster)")
    r.add_argument("--mode", choices=MODES, default=None,
                   help="tracker: thesis (default, §5.2's patch), listing (the literal port), plus "
                        "(seam map, holds the speed; docs/seamtrack.md)")
    r.add_argument("--cell", metavar="FILE",
                   help="run the trials on this cell file (a path, or a bundled cell's name): its layout, its "
                        "welder (the Reis, or the ABB on EGM) and its holder (docs/experiments.md)")
    r.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    r.add_argument("--record", action="store_true",
                   help="also record each lockstep trial as DIR/<table>/<id>.mcap (docs/observe.md)")
    r.add_argument("--length", type=bounded_float(0.0, MAX_RUN_LENGTH_MM, "mm", lo_open=True), default=None,
                   help=argparse.SUPPRESS)  # run length [mm]
    lp = sub.add_parser("list", help="list the experiments with their parameters, one a line")
    lp.add_argument("ids", nargs="*", metavar="ID", help="IDs or tables to list (default: all)")
    lp.add_argument("--plan", metavar="FILE", help="list a sweep plan's trials instead: index, ID, parameters")
    return p


def _cost(exp) -> float:
    """Relative cost of a trial: its simulated duration (run length / speed) [s]."""
    length = exp.config.length_mm or _seam_length_mm(exp.config.workpiece or "step_input")
    return length / exp.config.speed_mm_s


@functools.lru_cache(maxsize=64)
def _seam_length_mm(workpiece: str) -> float:
    from droid.sim.workpiece import load_workpiece

    return load_workpiece(workpiece).length_mm


class _NoBar:
    """The progress bar off: what tqdm's bar does when disabled (``update`` and the context do
    nothing), without importing tqdm (~10 ms of a process's start-up, issue 44)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> bool:
        return False

    def update(self, n: int = 1) -> None:
        pass


def _terminal(f) -> bool:
    try:
        return bool(f.isatty())
    except (AttributeError, ValueError):  # no isatty, or closed
        return False


def _progress(total: int):
    """The progress bar on stderr: tqdm's, shown only on a terminal (its ``disable=None`` rule)."""
    if not _terminal(sys.stderr):
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, file=sys.stderr, unit="trial", desc=PROG, dynamic_ncols=True, disable=None)


def _emit(line: str) -> None:
    """A summary line on stdout, around the bar when one may be shown (tqdm.write); the same bytes."""
    if "tqdm" not in sys.modules:  # no bar was made: nothing to clear and redraw
        sys.stdout.write(line)
        sys.stdout.write("\n")
        return
    from tqdm import tqdm

    tqdm.write(line, file=sys.stdout)


def run_jobs(jobs: list[Job], workers: int, dask: str | None = None) -> list[Outcome]:
    """Run the jobs (a pool when workers > 1, or a Dask cluster), storing and printing each as it comes."""
    outcomes: list[Outcome] = []
    warned: set[str] = set()

    def done(job: Job, o: Outcome) -> None:
        if not o.stored:
            store(job, o)
        outcomes.append(o)
        if o.figure_error and o.figure_error not in warned:
            warned.add(o.figure_error)
            print(f"{PROG}: {o.figure_error}", file=sys.stderr)
        if o.summary is not None and is_contact(o.exp):
            from droid.experiments.contact_trial import summary_line

            _emit(summary_line(o.summary))
        elif o.summary is not None:
            _emit(report.summary_line(o.summary))
        else:
            print(f"{PROG}: {o.exp.id}: {o.error}", file=sys.stderr)

    if not jobs:
        return outcomes
    if dask is not None:
        from droid.experiments.cluster import run_on_dask

        run_on_dask(jobs, dask, workers, run_job, done, _progress)
        return outcomes
    if workers <= 1 or len(jobs) == 1:
        with _progress(len(jobs)) as bar:
            for job in jobs:
                done(job, run_job(job))
                bar.update()
        return outcomes
    from droid.experiments.localpool import run_local

    with _progress(len(jobs)) as bar:
        def arrived(job: Job, o: Outcome) -> None:
            done(job, o)
            bar.update()

        run_local(jobs, workers, run_and_store, lambda job, why: Outcome(job.exp, None, why), arrived)
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
        ids = ", ".join(o.exp.id for o in outcomes)
        try:
            report.std_figure(os.path.join(d, "std.png"), grid, stds,
                              f"Experiment 4: standard deviation across runs {ids}")
            files.append(os.path.join(d, "std.png"))
        except ImportError:
            print(f"{PROG}: exp4: {NO_MATPLOTLIB}", file=sys.stderr)
    return files


# ---------------------------------------------------------------- plans

#: results.csv: the summary columns after the trial's parameters (report.Summary fields, + sim_s).
RESULT_COLUMNS = ("rows", "settled_rows", "settle_s_mm", "rms_lateral_mm", "max_lateral_mm", "rms_depth_mm",
                  "max_depth_mm", "end_s_mm", "seam_lost", "lost_s_mm", "stop_reason", "stop_detail",
                  "stop_s_mm", "sim_s", "error")


def _cell(v) -> str:
    """A results.csv cell: floats as repr (they read back exactly), NaN/None blank, booleans yes/no."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    return str(v)


def read_record(out_dir: str, trial: PlanTrial) -> dict | None:
    """A plan trial's stored record (its .json), or None when its results do not exist (or differ)."""
    path = os.path.join(out_dir, trial.id + ".json")
    try:
        with open(path) as f:
            rec = json.load(f)
    except (OSError, ValueError):
        return None
    if rec.get("trial_id") != trial.id or rec.get("params") != json_safe(trial.params):
        return None
    if not os.path.isfile(os.path.join(out_dir, trial.id + ".csv")):
        return None
    return rec


def write_results(out_dir: str, plan: Plan, errors: dict[str, str]) -> str:
    """results.csv: one row per trial of the plan, in plan order (trials without results: blank figures)."""
    path = os.path.join(out_dir, "results.csv")
    tmp = path + ".part"
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("index", "trial_id") + FIELDS + RESULT_COLUMNS)
        for t in plan.trials:
            rec = read_record(out_dir, t)
            row = [t.index, t.id] + [_cell(t.params[k]) for k in FIELDS]
            if rec is None:
                why = errors.get(t.id, "not run")
                row += [""] * (len(RESULT_COLUMNS) - 1) + [why]
            else:
                su = rec["summary"]
                figures = {k: su.get(k) for k in RESULT_COLUMNS if k in su}
                figures["sim_s"] = rec.get("sim_s")
                row += [_cell(figures.get(k)) for k in RESULT_COLUMNS[:-1]] + [""]
            w.writerow(row)
    os.replace(tmp, path)
    return path


def cmd_run_plan(args) -> int:
    for flag, value in (("--realtime", args.realtime), ("--seed", args.seed), ("--sensor", args.sensor),
                        ("--arm", args.arm), ("--length", args.length)):
        if value not in (None, False):
            raise BadInput(f"{flag} does not apply to --plan (set it in the plan's [defaults] or [sweep])")
    if args.cell is not None:
        raise BadInput("--cell does not apply to --plan (set the plan's top-level cell key)")
    if args.ids:
        raise BadInput(f"give experiment IDs or --plan, not both (got {' '.join(args.ids)})")
    dask = _check_dask(args.dask)
    plan = load_plan(args.plan)
    out_dir = os.path.join(args.out, plan.name)
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"--out {args.out}: {exc.strerror}") from None
    figures = not args.no_figures
    todo = list(plan.trials)
    skipped = 0
    if args.resume:
        todo = [t for t in plan.trials if read_record(out_dir, t) is None]
        skipped = len(plan.trials) - len(todo)
        print(f"{PROG}: {plan.name}: {skipped} of {len(plan.trials)} trial(s) have results; "
              f"running {len(todo)}", file=sys.stderr)
    jobs = [Job(t, out_dir, figures) for t in todo]
    workers = args.jobs or os.cpu_count() or 1
    jobs.sort(key=lambda j: (-_cost(j.exp), j.exp.index))  # longest first: the pool ends together
    t0 = time.perf_counter()
    outcomes: list[Outcome] = []
    try:
        outcomes = run_jobs(jobs, workers, dask)
    finally:  # also on Ctrl-C: results.csv shows what has results so far (a --resume completes it)
        errors = {o.exp.id: f"error: {o.error}" for o in outcomes if o.summary is None}
        if plan.trial == TRIAL_CONTACT:
            from droid.experiments.contact_report import write_results as write_contact_results

            results = write_contact_results(out_dir, plan, lambda t: read_record(out_dir, t), errors)
        else:
            results = write_results(out_dir, plan, errors)
    code = _report(outcomes, t0, workers, dask, f"{plan.name}: {len(outcomes)} trial(s) run, {skipped} resumed",
                   f"results: {results}")
    phases.mark("done")
    return code


def _report(outcomes: list[Outcome], t0: float, workers: int, dask: str | None, head: str, tail: str) -> int:
    """The one stderr line after a run or a --plan run (and the trials that failed); the exit status."""
    wall = time.perf_counter() - t0
    failed = [o.exp.id for o in outcomes if o.summary is None]
    sim = sum(o.sim_s for o in outcomes if o.summary is not None)
    where = f"Dask {dask}" if dask else f"{workers} worker(s)"
    print(f"{PROG}: {head}, {sim:.0f} s simulated in {wall:.1f} s wall on {where}; {tail}", file=sys.stderr)
    if failed:
        print(f"{PROG}: {len(failed)} trial(s) could not run: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


_DASK_ADDRESS = re.compile(r"(?:(?:tcp|tls|inproc|ws|wss|ucx)://)?[A-Za-z0-9_.\-\[\]:]+:[0-9]{1,5}")


def _check_dask(address: str | None) -> str | None:
    """``--dask``: ``local`` or a scheduler address (``tcp://host:8786``); BadInput otherwise."""
    if address is None or address == "local":
        return address
    if not _DASK_ADDRESS.fullmatch(address):
        raise BadInput(f"--dask {address!r}: expected a scheduler address such as tcp://HOST:8786, or local")
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise BadInput("--dask needs Dask distributed: pip install 'droid[cluster]'") from None
    return address


# ---------------------------------------------------------------- main

def cmd_list(names: Sequence[str], plan_spec: str | None = None) -> int:
    if plan_spec is not None:
        if names:
            raise BadInput(f"give experiment IDs or --plan, not both (got {' '.join(names)})")
        plan = load_plan(plan_spec)
        kind = f" {plan.trial}" if plan.trial == TRIAL_CONTACT else ""
        print(f"# {plan.name}: {len(plan.trials)}{kind} trial(s)"
              + (f" -- {plan.description}" if plan.description else ""))
        for t in plan.trials:
            print(t.describe())
        return 0
    for e in resolve(names or ["all"]):
        print(e.describe())
    return 0


def cmd_run(args) -> int:
    if args.plan is not None:
        return cmd_run_plan(args)
    if not args.ids:
        raise BadInput("experiment IDs are required (an ID, a table or all), or --plan FILE")
    if args.resume:
        raise BadInput("--resume applies to --plan runs")
    dask = _check_dask(args.dask)
    if dask and args.realtime:
        raise BadInput("--realtime runs on this host's process cell, not on --dask")
    if dask and args.record:
        raise BadInput("--record writes each trial's recording where the trial runs: not with --dask")
    picked = [with_seed(e, DEFAULT_SEED if args.seed is None else args.seed) for e in resolve(args.ids)]
    overrides = {"sensor": args.sensor or DEFAULT_SENSOR}
    if args.arm:
        overrides["arm"] = args.arm
    if args.cell is not None:
        overrides["cell"] = _trial_cell(args, picked)
    if getattr(args, "mode", None):
        overrides["mode"] = args.mode
    if args.length:
        overrides["length_mm"] = args.length
    picked = [replace(e, config=replace(e.config, **overrides)) for e in picked]
    figures = not args.no_figures
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"--out {args.out}: {exc.strerror}") from None
    jobs = [Job(e, os.path.join(args.out, e.table), figures, args.realtime, args.record) for e in picked]
    workers = 1 if args.realtime else (args.jobs or os.cpu_count() or 1)
    if workers > 1 or dask:
        jobs.sort(key=lambda j: -_cost(j.exp))  # longest first: the pool ends together
    t0 = time.perf_counter()
    outcomes = run_jobs(jobs, workers, dask)
    files = write_tables(args.out, outcomes, figures)
    code = _report(outcomes, t0, workers, dask, f"{len(outcomes)} trial(s)",
                   f"tables: {', '.join(f for f in files if f.endswith('summary.md')) or 'none'}")
    phases.mark("done")
    return code


def _trial_cell(args, picked: list) -> str:
    """``--cell``: the cell file's path, checked for every trial's arm and holder model before any
    runs (a missing file, a layout naming a subunit the cell lacks, a welder without a lockstep:
    one line, exit 2)."""
    from droid.sim.trial_cell import resolve_cell_path, resolve_trial_cell

    if args.realtime:
        raise BadInput("--cell runs lockstep trials only: --realtime builds its own cell from the built-in one "
                       "(on a cell of your own: droid-cell up --cell FILE, then droid-seamtrack --cell FILE)")
    path = resolve_cell_path(args.cell)
    for arm, holder in sorted({(args.arm or e.config.arm, e.config.holder) for e in picked}):
        resolve_trial_cell(path, arm, holder)
    return str(path)


@run
def main(argv: Sequence[str] | None = None) -> int:
    phases.mark("main")  # DROID_PHASES=1: the phase report (droid.experiments.phases)
    args = build_parser().parse_args(argv)
    if args.command == "list":
        return cmd_list(args.ids, args.plan)
    return cmd_run(args)


if __name__ == "__main__":
    sys.exit(main())
