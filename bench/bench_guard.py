"""One guard pass over every pair of the sim cell's bodies (issue 41; docs/guard.md).

Bodies: two 6R arms (the Reis with its tool and sensor, the Fanuc with its workpiece) and two
fixtures (the cell's floor and a table added here).  Each timed call gets a different
configuration (random joint vectors within the limits, drawn before timing), so nothing can
answer it from a cache.  Prints min / median / p99 of one pass [us] and the pairs checked.
Target (issue 41): <= 50 us.

Two figures each: the pass the guard runs (``scene.closest``: the compiled pass of droid._guard
where droid.guard.kernel chooses it, with the Python around it -- the dict of joint vectors, the
argmin), and the compiled call alone (``Scene.distances`` on a preallocated buffer), and for
comparison the numpy reference (``--reference``).

    nice -n 10 .venv/bin/python bench/bench_guard.py [--n 5000] [--batch] [--reference]
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from droid.cli import ArgumentParser, bounded_int
from droid.brain.cell.cellfile import load_cell
from droid.guard.bodies import FIXTURE, Body
from droid.guard.cell import GuardScene, guard_scene
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T

CELL = Path(__file__).resolve().parents[1] / "cells" / "sim.toml"


def bench_scene() -> GuardScene:
    s = guard_scene(load_cell(CELL))
    table = Body(FIXTURE, "table", "box", T=pose_to_T(1000.0, 900.0, 400.0, 0.0, 0.0, 0.0), half_mm=np.array([400.0, 300.0, 20.0]))
    allow = {frozenset((a.key, b.key)) for a, b in _all_pairs(s)} - {frozenset((a.key, b.key)) for a, b in s.pairs}
    return GuardScene(s.arms, s.bodies + [table], allow)


def _all_pairs(s):
    return [(a, b) for i, a in enumerate(s.bodies) for b in s.bodies[i + 1:]]


def main() -> None:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=bounded_int(1, 1_000_000), default=5000, help="timed passes")
    ap.add_argument("--batch", action="store_true", help="also time a batch of --n configurations in one call")
    ap.add_argument("--reference", action="store_true", help="also time the numpy reference pass")
    args = ap.parse_args()
    cell = load_cell(CELL)
    scene = bench_scene()
    rng = np.random.default_rng(1)
    qs = {}
    for name in scene.arms:
        m = load_robot(cell.subunits[name].robot)
        qs[name] = rng.uniform(m.joint_min_deg, m.joint_max_deg, size=(args.n, 6))
    kinds = [f"{a.kind[0]}{b.kind[0]}" for a, b in scene.pairs]
    print(f"bodies {len(scene.bodies)}, pairs {scene.n_pairs} (capsule-capsule {kinds.count('cc')}, "
          f"capsule-box {kinds.count('cb')}, box-box {kinds.count('bb')}); compiled: {scene.compiled is not None}")

    def timed(what: str, call) -> None:
        for i in range(200):  # warm up
            call(i % args.n)
        t = np.empty(args.n)
        for i in range(args.n):
            t0 = time.perf_counter_ns()
            call(i)
            t[i] = time.perf_counter_ns() - t0
        t /= 1000.0
        print(f"{what} [us]: min {t.min():.1f}  median {np.median(t):.1f}  p99 {np.percentile(t, 99):.1f}"
              f"  (n {args.n}; target <= 50)")

    rows = [{k: v[i] for k, v in qs.items()} for i in range(args.n)]
    timed("one guard pass (scene.closest)", lambda i: scene.closest(rows[i]))
    if scene.compiled is not None:
        flat = np.ascontiguousarray(np.stack([qs[n] for n in scene.arms], axis=1))  # (n, arms, 6)
        out = np.empty(scene.n_pairs)
        timed("the compiled call alone (Scene.distances)", lambda i: scene.compiled.distances(flat[i], out))
    if args.reference:
        timed("the numpy reference (distances_reference)", lambda i: scene.distances_reference(
            {k: v.reshape(1, 6) for k, v in rows[i].items()}))
    if args.batch:
        t0 = time.perf_counter()
        scene.distances(qs)
        dt = time.perf_counter() - t0
        print(f"batch of {args.n} configurations in one call: {dt * 1e6 / args.n:.2f} us a configuration")


if __name__ == "__main__":
    main()
