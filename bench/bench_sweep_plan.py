"""The 200-trial sweep plan three ways (issue 15; docs/experiments.md, "Measured"):

1. on the local process pool, uninterrupted (the reference);
2. on the local pool, interrupted by SIGINT (as Ctrl-C) part-way, then ``--resume``d;
3. on a Dask cluster of a scheduler and two single-threaded workers on loopback.

Prints the wall time of each run and whether the three ``results.csv`` are
identical, byte for byte.  Usage::

    python bench/bench_sweep_plan.py [--plan sweep200] [--out DIR] [--jobs 2] [--interrupt-at 80] [--figures]
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from droid.cli import ArgumentParser, bounded_int

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "droid.experiments.cli"]
DASK = str(Path(sys.executable).parent / "dask")


def _default_sigint() -> None:
    # a shell's background job (`cmd &`) starts with SIGINT ignored, and a program that starts so keeps
    # ignoring it (as nohup wants): give the interrupted run a terminal's Ctrl-C semantics
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def run(args: list[str]) -> float:
    t0 = time.perf_counter()
    p = subprocess.run(CLI + args, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        sys.exit(f"{' '.join(args)}: exit {p.returncode}: {p.stderr.strip().splitlines()[-1:]}")
    print("   ", p.stderr.strip().splitlines()[-1])
    return wall


def main() -> None:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plan", default="sweep200")
    ap.add_argument("--out", default=None)
    ap.add_argument("--jobs", type=bounded_int(1, 256, "processes"), default=2, help="parallel processes")
    ap.add_argument("--interrupt-at", type=bounded_int(1, 10**6, "trials"), default=80,
                    help="SIGINT once this many trials have results")
    ap.add_argument("--figures", action="store_true", help="draw the PNGs too (default: --no-figures)")
    a = ap.parse_args()
    out = Path(a.out or tempfile.mkdtemp(prefix="droid-sweep-"))
    figs = [] if a.figures else ["--no-figures"]
    name = a.plan if not a.plan.endswith(".toml") else Path(a.plan).stem
    print(f"plan {a.plan}, {a.jobs} jobs, figures {'on' if a.figures else 'off'}, out {out}")
    print(f"load average before: {os.getloadavg()}")

    print("1. local pool, uninterrupted")
    w1 = run(["run", "--plan", a.plan, "--out", str(out / "pool"), "--jobs", str(a.jobs)] + figs)

    print(f"2. local pool, SIGINT after {a.interrupt_at} trials, then --resume")
    d = out / "resumed" / name
    t0 = time.perf_counter()
    proc = subprocess.Popen(CLI + ["run", "--plan", a.plan, "--out", str(out / "resumed"), "--jobs", str(a.jobs)]
                            + figs, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_default_sigint)
    while proc.poll() is None and len(list(d.glob("*.json"))) < a.interrupt_at:
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate()
    done = len(list(d.glob("*.json")))
    print(f"    interrupted: exit {proc.returncode}, {done} trial(s) had results")
    w2 = time.perf_counter() - t0 + run(["run", "--plan", a.plan, "--out", str(out / "resumed"), "--jobs",
                                         str(a.jobs), "--resume"] + figs)

    print("3. Dask: a scheduler and 2 workers on 127.0.0.1")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    log = open(out / "dask.log", "w")
    procs = [subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              env=env(), stdout=log, stderr=log)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen([DASK, "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                                           "--no-dashboard", "--local-directory", str(out / "workers")],
                                          env=env(), stdout=log, stderr=log))
        from distributed import Client

        with Client(address, timeout=60) as c:
            c.wait_for_workers(2, timeout=120)
        w3 = run(["run", "--plan", a.plan, "--out", str(out / "dask"), "--dask", address] + figs)
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs[::-1]:
            p.wait()
    results = [(out / k / name / "results.csv").read_bytes() for k in ("pool", "resumed", "dask")]
    rows = len(results[0].splitlines()) - 1
    print(f"results.csv: {rows} rows; resumed == uninterrupted: {results[1] == results[0]}; "
          f"dask == pool: {results[2] == results[0]}")
    print(f"wall [s]: pool {w1:.1f}, interrupted+resumed {w2:.1f}, dask 2 workers {w3:.1f}")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
