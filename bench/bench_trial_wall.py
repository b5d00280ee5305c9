"""What a user waits for: ``droid-experiment run ID`` as a process, from exec to exit (issue 44 item 1).

Runs each trial of a varied set as its own process -- ``python -c "from droid.experiments.cli
import main; ..."``, what the ``droid-experiment`` console script does, ``--jobs 1``, the trial's
default figures on unless ``--no-figures`` -- with ``DROID_PHASES=1`` (the phase report of
droid.experiments.phases: one stderr line per phase boundary with a CLOCK_MONOTONIC time, the
process's CPU time and the scheduler's simulated time) and splits the process's wall time into:

==============  ======================================================================
imports         exec to ``main()``: the interpreter's start-up and the command line's imports
setup           ``main()`` to the trial's job: arguments, the experiments resolved, the job
build           the cell resolved and checked, the geometry, the welder built (lockstep builders imported)
homing          the welder's homing (the Reis: the limit-switch search), with its simulated seconds
approach        the move to the start pose and the settling, with its simulated seconds
ready           the holder built, homed and at its holding pose (the GMF1), the cycle, the sensors
trial           the trial's loop, with its simulated seconds
figure          the summary and the figure (matplotlib's import and drawing)
write           the files and the tables written, the last line printed
exit            ``main()``'s return to the process's exit (the interpreter's teardown)
==============  ======================================================================

and prints, per trial, each phase's wall seconds, the whole process's wall and CPU seconds
(``os.wait4``'s rusage of the child: user + system), the trial's simulated seconds and the
"x real time" figures: simulated trial seconds / whole-process wall seconds (what a user waits
for, start-up and homing included) and the same per CPU second of the process; then the same
split in CPU seconds.  The machine is shared: the load average is printed before and after each
run; read the CPU figures beside the wall ones.

The set (``--only`` picks some, by name): ``1.3``, ``1.12``, ``2.1`` (chapter 6, the full arm,
seed 1), ``helix`` (a plan's 3-D trial: the workpieces plan's helix_r300 at 16 mm/s, ideal
sensor, 400 mm -- its trial 2 -- as a one-trial plan written to a temporary directory), ``abb``
(``1.3 --cell cells/abb_weld.toml --mode plus``: the ABB on EGM) and ``contact`` (the
contact_seeds plan's seed 1: 20 N at 10 mm/s over 200 mm, as a one-trial plan).

``--base DIR`` also runs each trial on an old checkout's tree (``PYTHONPATH`` = DIR, its
compiled extension built or copied there), alternating with this one, for a before/after
figure; an old tree without the phase report gives the whole process only.  ``--imports N``
instead times the imports: N runs of ``python -X importtime -c "import droid.experiments.cli"``
(the module's cumulative import time, min/median) and one ``-X importtime`` run of ``run 1.12``
(``--no-figures`` and figures: every module the run imports, the heaviest top-level ones).

Timing is measured here, never in tests (docs/benchmarks.md).  Usage::

    python bench/bench_trial_wall.py [--only 1.12,abb] [--repeat 1] [--no-figures] [--base DIR] [--json]
    python bench/bench_trial_wall.py --imports 5 [--base DIR]
"""
from __future__ import annotations

import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
TREE = HERE.parent.parent
sys.path.insert(0, str(TREE))

from droid.cli import ArgumentParser, bounded_int  # noqa: E402
LAUNCH = ("import sys; sys.argv[0] = 'droid-experiment'; from droid.experiments.cli import main; "
          "sys.exit(main())")

HELIX_PLAN = """name = "bench_helix"
description = "the workpieces plan's trial 2: helix_r300, 16 mm/s, ideal sensor, 400 mm"
[defaults]
workpiece = "helix_r300"
position = "i"
speed_mm_s = 16
sensor = "ideal"
length_mm = 400
seed = 1
"""
CONTACT_PLAN = """name = "bench_contact"
description = "the contact_seeds plan's seed 1: 20 N at 10 mm/s over 200 mm"
trial = "contact"
[defaults]
force_n = 20
speed_mm_s = 10
length_mm = 200
seed = 1
"""

#: name -> droid-experiment run's arguments ({plans}: the temporary directory of the plan files)
TRIALS = {
    "1.3": ["1.3", "--seed", "1"],
    "1.12": ["1.12", "--seed", "1"],
    "2.1": ["2.1", "--seed", "1"],
    "helix": ["--plan", "{plans}/bench_helix.toml"],
    "abb": ["1.3", "--seed", "1", "--cell", "cells/abb_weld.toml", "--mode", "plus"],
    "contact": ["--plan", "{plans}/bench_contact.toml"],
}
#: (column, from boundary, to boundary); None: the process's exec / exit
SPLIT = (("imports", None, "main"), ("setup", "main", "trial"), ("build", "trial", "built"),
         ("homing", "built", "homed"), ("approach", "homed", "approached"), ("ready", "approached", "ready"),
         ("trial", "ready", "tracked"), ("figure", "tracked", "figure"), ("write", "figure", "done"),
         ("exit", "done", None))


def _load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def run_one(tree: Path, args: list[str], out: str) -> dict:
    """One ``droid-experiment run`` process on ``tree``: wall from exec to exit, the child's CPU,
    the phase records, and the simulated seconds."""
    env = dict(os.environ, DROID_PHASES="1", PYTHONPATH=str(tree))
    load0 = _load()
    with tempfile.TemporaryFile() as so, tempfile.TemporaryFile() as se:
        t0 = time.monotonic()
        p = subprocess.Popen([sys.executable, "-c", LAUNCH, "run", *args, "--jobs", "1", "--out", out],
                             cwd=str(tree), env=env, stdout=so, stderr=se)
        _, status, ru = os.wait4(p.pid, 0)
        t1 = time.monotonic()
        p.returncode = os.waitstatus_to_exitcode(status)
        so.seek(0), se.seek(0)
        stdout, stderr = so.read().decode(), se.read().decode()
    if p.returncode != 0:
        raise SystemExit(f"droid-experiment run {' '.join(args)} on {tree} exited {p.returncode}:\n{stderr[-3000:]}")
    recs = []
    for line in stderr.splitlines():
        if line.startswith("droid-phase "):
            recs.append(json.loads(line[len("droid-phase "):]))
    at = {r["phase"]: r for r in recs}
    rec = {"wall_s": t1 - t0, "cpu_s": ru.ru_utime + ru.ru_stime, "user_s": ru.ru_utime, "sys_s": ru.ru_stime,
           "maxrss_mb": ru.ru_maxrss / 1024, "load_before": load0, "load_after": _load(), "stdout": stdout.strip()}
    m = re.search(r"([0-9.]+) s simulated in", stderr)
    rec["sim_total_s"] = float(m.group(1)) if m else None  # the run's own line (rounded; contact: homing included)
    if at:
        clock = {None: (t0, 0.0)}
        wall, cpu = {}, {}
        for col, a, b in SPLIT:
            ta, ca = clock[None] if a is None else (at[a]["t"], at[a]["cpu_s"])
            tb, cb = (t1, rec["cpu_s"]) if b is None else (at[b]["t"], at[b]["cpu_s"])
            wall[col], cpu[col] = tb - ta, cb - ca
        rec["wall"], rec["cpu"] = wall, cpu
        rec["sim"] = {"homing": at["homed"]["sim_s"] - at["built"]["sim_s"],
                      "approach": at["approached"]["sim_s"] - at["homed"]["sim_s"],
                      "ready": at["ready"]["sim_s"] - at["approached"]["sim_s"],
                      "trial": at["tracked"]["sim_s"] - at["ready"]["sim_s"]}
    return rec


def _fmt(v, w=7, d=2) -> str:
    return f"{v:{w}.{d}f}" if isinstance(v, (int, float)) else f"{'-':>{w}}"


def print_tables(results: dict, sim_of: dict) -> None:
    cols = [c for c, _, _ in SPLIT]
    for what in ("wall", "cpu"):
        print(f"\n# {what} seconds per phase; whole process: wall and CPU; sim = the trial's simulated seconds "
              "(homing's in brackets); x real = sim / whole-process wall, x CPU = sim / process CPU")
        print(f"{'trial':<14}" + "".join(f"{c:>9}" for c in cols)
              + f"{'wall':>8}{'CPU':>8}{'sim':>8}{'(home)':>8}{'x real':>8}{'x CPU':>8}  load before/after")
        for key, recs in results.items():
            for r in recs:
                split = r.get(what, {})
                sim = r.get("sim", {}).get("trial", sim_of.get(key[1]))
                home = r.get("sim", {}).get("homing")
                print(f"{key[0] + ' ' + key[1]:<14}" + "".join(_fmt(split.get(c), 9) for c in cols)
                      + _fmt(r["wall_s"], 8) + _fmt(r["cpu_s"], 8) + _fmt(sim, 8, 1)
                      + (f"{'(' + format(home, '.1f') + ')':>8}" if home is not None else f"{'':>8}")
                      + _fmt(sim / r["wall_s"] if sim else None, 8, 1)
                      + _fmt(sim / r["cpu_s"] if sim else None, 8, 1)
                      + f"  {r['load_before']} / {r['load_after']}")


def imports_bench(trees: dict, n: int) -> dict:
    """-X importtime of ``import droid.experiments.cli`` (n runs) and of one ``run 1.12`` each way."""
    out = {}
    for name, tree in trees.items():
        env = dict(os.environ, PYTHONPATH=str(tree))
        cum, walls, cpus = [], [], []
        for _ in range(n):
            t0 = time.monotonic()
            r = subprocess.run([sys.executable, "-X", "importtime", "-c", "import droid.experiments.cli"],
                               cwd=str(tree), env=env, capture_output=True, text=True, check=True)
            walls.append(time.monotonic() - t0)
            line = [ln for ln in r.stderr.splitlines() if ln.rstrip().endswith("| droid.experiments.cli")][-1]
            cum.append(int(line.split("|")[1]) / 1e6)
            r = subprocess.run([sys.executable, "-c", "import time, droid.experiments.cli; print(time.process_time())"],
                               cwd=str(tree), env=env, capture_output=True, text=True, check=True)
            cpus.append(float(r.stdout))  # the process's CPU: the interpreter's start-up and the import
        rec = {"cli_import_s": {"min": min(cum), "median": statistics.median(cum)},
               "cli_process_wall_s": {"min": min(walls), "median": statistics.median(walls)},
               "cli_process_cpu_s": {"min": min(cpus), "median": statistics.median(cpus)}, "load": _load()}
        for label, extra in (("run_no_figures", ["--no-figures"]), ("run_figures", [])):
            best = None
            for _ in range(min(n, 5)):  # the run with the least import time of up to 5
                tmp = tempfile.mkdtemp(prefix="bench-imports-")
                try:
                    r = subprocess.run([sys.executable, "-X", "importtime", "-c", LAUNCH, "run", "1.12", "--seed",
                                        "1", "--length", "10", "--jobs", "1", "--out", tmp, *extra],
                                       cwd=str(tree), env=env, capture_output=True, text=True, check=True)
                finally:
                    shutil.rmtree(tmp, ignore_errors=True)
                top, total, mods = [], 0, 0
                for ln in r.stderr.splitlines():  # "import time: SELF | CUMULATIVE | <2 spaces a level>NAME"
                    if not ln.startswith("import time:") or "self [us]" in ln:
                        continue
                    mods += 1
                    _, cum_us, mod = ln.split("|", 2)
                    if mod.startswith("  "):  # nested: counted in its top-level parent's cumulative time
                        continue
                    total += int(cum_us)
                    top.append((int(cum_us) / 1e6, mod.strip()))
                top.sort(reverse=True)
                if best is None or total / 1e6 < best["import_s"]:
                    best = {"modules": mods, "import_s": total / 1e6, "top": [(round(s, 3), m) for s, m in top[:12]]}
            rec[label] = best
        out[name] = rec
    return out


def machine() -> str:
    cpu = ""
    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return (f"{time.strftime('%Y-%m-%d %H:%M:%S %Z')}  {platform.machine()} {cpu!r}, {os.cpu_count()} CPUs, "
            f"Python {platform.python_version()}")


def main(argv=None) -> int:
    ap = ArgumentParser(prog="bench_trial_wall", description=__doc__.split("\n")[0])
    ap.add_argument("--only", help=f"comma-separated trial names (of {', '.join(TRIALS)})")
    ap.add_argument("--repeat", type=bounded_int(1, 100), default=1, help="runs of each trial (and tree)")
    ap.add_argument("--no-figures", action="store_true", help="pass --no-figures")
    ap.add_argument("--base", help="an old checkout's top directory, run beside this tree, alternating")
    ap.add_argument("--imports", type=bounded_int(0, 100), default=0, metavar="N",
                    help="time the imports instead (N runs)")
    ap.add_argument("--json", action="store_true", help="also print one JSON object at the end")
    args = ap.parse_args(argv)
    trees = {"this": TREE}
    if args.base:
        base = Path(args.base).resolve()
        if not (base / "droid" / "experiments" / "cli.py").is_file():
            raise SystemExit(f"--base: {base}/droid/experiments/cli.py not found")
        trees = {"base": base, "this": TREE}
    print(f"# bench_trial_wall  {machine()}  load average {_load()}")
    for tree in trees.values():  # byte-compiled first (a fresh checkout's first run would compile it)
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "droid")], check=True,
                       stdout=subprocess.DEVNULL)
    if args.imports:
        res = imports_bench(trees, args.imports)
        for name, rec in res.items():
            print(f"\n## {name}: import droid.experiments.cli: {rec['cli_import_s']['min']:.3f} s min, "
                  f"{rec['cli_import_s']['median']:.3f} s median (-X importtime, {args.imports} runs); the process "
                  f"(python -X importtime -c ...): {rec['cli_process_wall_s']['min']:.3f} s min wall; without "
                  f"-X importtime, its CPU at the end of the import: {rec['cli_process_cpu_s']['min']:.3f} s min, "
                  f"{rec['cli_process_cpu_s']['median']:.3f} s median; load {rec['load']}")
            for label in ("run_no_figures", "run_figures"):
                r = rec[label]
                print(f"   run 1.12 --length 10 ({label}): {r['modules']} modules, {r['import_s']:.3f} s of imports (top "
                      f"level, cumulative; the least of {min(args.imports, 5)} runs); heaviest: " + ", ".join(f"{m} {s:.3f}" for s, m in r["top"][:8]))
        if args.json:
            print(json.dumps(res))
        return 0
    names = args.only.split(",") if args.only else list(TRIALS)
    for n in names:
        if n not in TRIALS:
            raise SystemExit(f"--only: unknown trial {n!r} (known: {', '.join(TRIALS)})")
    plans = tempfile.mkdtemp(prefix="bench-trial-wall-")
    results: dict = {}
    try:
        Path(plans, "bench_helix.toml").write_text(HELIX_PLAN)
        Path(plans, "bench_contact.toml").write_text(CONTACT_PLAN)
        for n in names:
            targs = [a.format(plans=plans) for a in TRIALS[n]] + (["--no-figures"] if args.no_figures else [])
            for _ in range(args.repeat):
                for tname, tree in trees.items():
                    out = tempfile.mkdtemp(prefix="out-", dir=plans)
                    r = run_one(tree, targs, out)
                    results.setdefault((tname, n), []).append(r)
                    print(f"# {tname} {n}: {r['wall_s']:.2f} s wall, {r['cpu_s']:.2f} s CPU; "
                          f"load {r['load_before']} -> {r['load_after']}", flush=True)
    finally:
        shutil.rmtree(plans, ignore_errors=True)
    sim_of = {}
    for (tname, n), recs in results.items():
        for r in recs:
            if "sim" in r:
                sim_of[n] = r["sim"]["trial"]  # the same trial on every tree (the logs are bit-identical)
    print_tables(results, sim_of)
    print(f"\n# load average at the end {_load()}")
    if args.json:
        print(json.dumps({f"{t} {n}": recs for (t, n), recs in results.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
