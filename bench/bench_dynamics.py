"""Time per call of an arm's rigid-body dynamics: the compiled kernel against Pinocchio.

:class:`droid.arm.rigid_body.RigidBody` with ``backend="kernel"`` (droid/_kernel.c ``rb_*``:
RNEA, CRBA, a Cholesky solve; droid-sim's world) and ``backend="pinocchio"`` (lockstep trials),
each method called through the RigidBody as the plant and the contact call it, on a pool of
random states (joint angles over two turns, speeds to 6 rad/s, torques over six decades) cycled
so that no two consecutive calls see the same input (neither library caches across calls, but a
repeated input would flatter branch prediction).  Also the resident size of a fresh process
after importing each backend (VmRSS, /proc/self/status).

Figures are min and median over ``--rounds`` rounds of ``--calls`` calls each [us per call],
thread CPU time.  Timing is measured here, never in tests (docs/benchmarks.md).  Usage::

    PYTHONPATH=. python bench/bench_dynamics.py [--robot reis_v15] [--calls 20000] [--rounds 5] [--json]
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
METHODS = ("nle", "gravity", "mass", "minv", "aba", "joint6_jacobian_world", "wcp_mm")


def _states(n: int, seed: int = 11):
    import numpy as np

    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.0 * np.pi, 2.0 * np.pi, (n, 6))
    qd = rng.uniform(-6.0, 6.0, (n, 6))
    tau = rng.standard_normal((n, 6)) * 10.0 ** rng.uniform(-3, 3, (n, 6))
    return [(q[i].copy(), qd[i].copy(), tau[i].copy(), np.degrees(q[i])) for i in range(n)]


def _calls(body, method: str):
    """A function of one state that makes the call."""
    f = getattr(body, method)
    if method == "nle":
        return lambda s: f(s[0], s[1])
    if method == "aba":
        return lambda s: f(s[0], s[1], s[2])
    if method == "wcp_mm":
        return lambda s: f(s[3])
    return lambda s: f(s[0])


def time_methods(robot: str, calls: int, rounds: int) -> dict:
    from droid.kinematics import load_robot
    from droid.arm.rigid_body import RigidBody

    m = load_robot(robot)
    bodies = {b: RigidBody(m.dh, m.dynamics, backend=b) for b in ("kernel", "pinocchio")}
    pool = _states(997)  # a prime: the pool's phase shifts each round
    clock = time.thread_time
    out: dict = {}
    for method in METHODS:
        out[method] = {}
        per = {b: [] for b in bodies}
        fns = {b: _calls(body, method) for b, body in bodies.items()}
        for _ in range(rounds):
            for b, fn in fns.items():  # alternating: both see the same load
                states = [pool[i % len(pool)] for i in range(calls)]
                t0 = clock()
                for s in states:
                    fn(s)
                per[b].append(1e6 * (clock() - t0) / calls)
        for b, v in per.items():
            out[method][b] = {"min": round(min(v), 3), "median": round(statistics.median(v), 3)}
        out[method]["speedup_min"] = round(out[method]["pinocchio"]["min"] / out[method]["kernel"]["min"], 2)
    return out


RSS_SCRIPT = """
import sys
def rss():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1])
base = rss()
import numpy
from droid.kinematics import load_robot
from droid.arm.rigid_body import RigidBody
m = load_robot("{robot}")
body = RigidBody(m.dh, m.dynamics, backend="{backend}")
body.nle(numpy.zeros(6), numpy.zeros(6))
print(base, rss(), int("pinocchio" in sys.modules))
"""


def rss_kb(robot: str, backend: str) -> dict:
    r = subprocess.run([sys.executable, "-c", RSS_SCRIPT.format(robot=robot, backend=backend)],
                       env=dict(os.environ, PYTHONPATH=str(HERE.parent.parent)), capture_output=True, text=True,
                       timeout=120, check=True)
    base, after, pin = (int(x) for x in r.stdout.split())
    return {"interpreter_kb": base, "after_kb": after, "pinocchio_imported": bool(pin)}


def main(argv=None) -> int:
    from droid.cli import ArgumentParser, bounded_int

    ap = ArgumentParser(prog="bench_dynamics", description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default="reis_v15", help="a bundled robot with [dynamics] (default reis_v15)")
    ap.add_argument("--calls", type=bounded_int(100, 10_000_000, "calls"), default=20000, help="calls per round")
    ap.add_argument("--rounds", type=bounded_int(1, 100, "rounds"), default=5, help="rounds per backend")
    ap.add_argument("--json", action="store_true", help="one JSON object")
    args = ap.parse_args(argv)
    out = {"robot": args.robot, "calls": args.calls, "rounds": args.rounds,
           "times_us": time_methods(args.robot, args.calls, args.rounds),
           "rss": {b: rss_kb(args.robot, b) for b in ("kernel", "pinocchio")},
           "load_average": [round(x, 2) for x in os.getloadavg()]}
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{args.robot}: us per call (thread CPU), min / median of {args.rounds} rounds of {args.calls} calls")
    print(f"{'method':24s} {'kernel':>17s} {'pinocchio':>17s} {'speed-up':>9s}")
    for method, v in out["times_us"].items():
        k, p = v["kernel"], v["pinocchio"]
        print(f"{method:24s} {k['min']:8.3f} {k['median']:8.3f} {p['min']:8.3f} {p['median']:8.3f} "
              f"{v['speedup_min']:8.2f}x")
    for b, v in out["rss"].items():
        print(f"RSS of a fresh process with the {b} backend: {v['after_kb'] / 1024:.1f} MB "
              f"(interpreter alone {v['interpreter_kb'] / 1024:.1f} MB; pinocchio imported: {v['pinocchio_imported']})")
    print(f"load average {out['load_average']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
