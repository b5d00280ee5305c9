#!/usr/bin/env python3
"""Benchmarks of the GMF1 bridge (issue 5): prints figures, decides nothing.

  command-to-completion   a Brain command written -> Status says cmd_id done (busy 0); small moves
                          (1 mm, the motion itself takes ~10 ms) so the figure is the bridge's
                          overhead: heartbeat relay, 9600-baud line both ways, the KAREL
                          interpreter's reply delay, DONE, relay back.  Also "minus motion":
                          latency minus the controller's planned duration (lockstep knows it).
  status refresh age      age of the pose in the controller's Status record (updated_ns) when
                          sampled at random instants — the encoder program's 120 Hz; real time
                          also the Brain Status (tick-driven copy by droid-remote)
  lockstep speed          virtual seconds per wall second of the GMF1 lockstep (1 kHz world)

Usage: bench/bench_gmf1.py [--mode lockstep|realtime|both] [--moves 40]
Record the printed figures with the machine and date in docs/bench-gmf1.md.
"""
from __future__ import annotations

import os
import platform
import random
import shutil
import subprocess
import sys
import tempfile
import time
import uuid

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from droid.cli import ArgumentParser, bounded_int  # noqa: E402
from droid.kinematics.transforms import T_to_pose, pose_to_T  # noqa: E402

BASE_Q = np.array([0.0, 10.0, 10.0, 0.0, 40.0, 20.0])


def pct(v, q):
    return float(np.percentile(np.asarray(v, float), q))


def line(label, values, unit="ms"):
    v = np.asarray(values, float)
    print(f"  {label:<50} median {np.median(v):8.2f} {unit}   p99 {pct(v, 99):8.2f} {unit}   "
          f"max {v.max():8.2f} {unit}   (n={len(v)})")


def targets(model, n):
    """n small moves (1 mm steps back and forth in y) around a comfortable pose, global frame."""
    p = T_to_pose(model.fk(BASE_Q))
    return [p + np.array([0, (k % 2) * 1.0, 0, 0, 0, 0]) for k in range(1, n + 1)]


# -- lockstep ----------------------------------------------------------------------------
def bench_lockstep(moves: int) -> None:
    from droid.sim.gmf1.lockstep import Gmf1Lockstep

    print("lockstep (virtual time, 1 kHz world, 60 Hz heartbeat, 120 Hz encoder)")
    wall0 = time.perf_counter()
    g = Gmf1Lockstep()
    g.run_ticks(2)
    if not g.home():
        raise SystemExit("bench_gmf1: the lockstep GMF1 did not home")
    start = T_to_pose(g.model.fk(BASE_Q))
    cid = g.command_cart(pose_to_T(*start), g.ticks_for(1.0))
    g.run_until(lambda: g.done(cid), 20)
    for label, pause_s in (("back to back", 0.0), ("isolated, 0.5 s idle before", 0.5)):
        lat, net = [], []
        for tgt in targets(g.model, moves):
            g.sched.run_for(pause_s)
            t0 = g.t_s
            cid = g.command_cart(pose_to_T(*tgt), g.ticks_for(1 / 60))
            g.run_until(lambda: g.done(cid), 20)
            dt = g.t_s - t0
            lat.append(dt * 1e3)
            net.append((dt - g.controller.last_duration_s) * 1e3)
        line(f"command-to-completion, {label}", lat)
        line("  minus the planned motion", net)
    # refresh age at random instants
    rng = random.Random(1)
    ages = []
    for _ in range(2000):
        g.sched.run_for(rng.uniform(0.0, 0.05))
        ages.append((g.sched.t_ns - int(g.status()["updated_ns"])) / 1e6)
    line("status refresh age (ctrl_status)", ages)
    virt = g.t_s
    wall = time.perf_counter() - wall0
    print(f"  lockstep speed                                     {virt / wall:8.1f} x real time "
          f"({virt:.1f} virtual s in {wall:.2f} s)")
    print(f"  controller: {g.controller.accepted} moves, {g.controller.busy_rejects} BUSY; serial: "
          f"dropped {g.serial_core.dropped}, timeouts {g.serial_core.timeouts}")


# -- real time -----------------------------------------------------------------------------
def bench_realtime(moves: int) -> None:
    from droid.brain.cell.cellfile import builtin_cell_path, load_cell
    from droid.brain.db.databases import open_brain, open_local
    from droid.brain.db import arm_command
    from droid.kinematics import load_robot
    from droid.kinematics.transforms import pose_to_T

    name = f"bench{uuid.uuid4().hex[:6]}"
    tmp = tempfile.mkdtemp(prefix="droid-bench-gmf1-")
    text = builtin_cell_path().read_text().replace('name = "sim"', f'name = "{name}"\nrun_dir = "{tmp}/run"', 1)
    path = os.path.join(tmp, "cell.toml")
    with open(path, "w") as f:
        f.write(text)
    py = [sys.executable, "-m"]
    env = dict(os.environ, PYTHONPATH=os.path.join(os.path.dirname(__file__), ".."))

    def run(*args, check=True):
        out = subprocess.run(py + list(args) + ["--cell", path], capture_output=True, text=True, env=env)
        if check and out.returncode:
            raise SystemExit(f"{' '.join(args)}: {out.stderr.strip()}")
        return out

    print(f"real time (the whole sim cell: {name}, all programs as processes)")
    run("droid.brain.runtime.launcher", "up")
    try:
        cell = load_cell(path)
        sub = cell.subunit("gmf1")
        model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))
        run("droid.tasks.home", "gmf1")
        start = T_to_pose(model.fk(BASE_Q))
        run("droid.tasks.move", "gmf1", "cart", *[f"{v:.4f}" for v in start], "1.5")
        status = open_brain(cell, sub, "status")
        command = open_brain(cell, sub, "command")
        ctrl = open_local(cell, sub, "ctrl_status")
        for label, pause_s in (("back to back", 0.0), ("isolated, 0.5 s idle before", 0.5)):
            lat = []
            for tgt in targets(model, moves):
                time.sleep(pause_s)
                T = pose_to_T(*tgt)
                while int(status.read()["busy"]):
                    time.sleep(0.001)
                t0 = time.monotonic()
                cid = arm_command.cart(command, T, 1)
                deadline = t0 + 10
                while time.monotonic() < deadline:
                    r = status.read()
                    if int(r["cmd_id"]) == cid and int(r["busy"]) == 0:
                        break
                    time.sleep(0.0005)
                lat.append((time.monotonic() - t0) * 1e3)
            line(f"command-to-completion, {label} (Brain)", lat)
        rng = random.Random(2)
        ages_c, ages_b = [], []
        for _ in range(1500):
            time.sleep(rng.uniform(0.0, 0.01))
            now = time.monotonic_ns()
            ages_c.append((now - int(ctrl.read()["updated_ns"])) / 1e6)
            ages_b.append((time.monotonic_ns() - int(status.read()["updated_ns"])) / 1e6)
        line("status refresh age (ctrl_status)", ages_c)
        line("status refresh age (Brain Status)", ages_b)
        for db in (status, command, ctrl):
            db.close()
    finally:
        run("droid.brain.runtime.launcher", "down", check=False)
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("lockstep", "realtime", "both"), default="both")
    ap.add_argument("--moves", type=bounded_int(1, 100_000, "moves"), default=40, help="moves to time")
    args = ap.parse_args()
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} CPUs, "
          f"Python {platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M')}")
    if args.mode in ("lockstep", "both"):
        bench_lockstep(args.moves)
    if args.mode in ("realtime", "both"):
        bench_realtime(args.moves)


if __name__ == "__main__":
    main()
