"""CPU per world step of the default cell's droid-sim, idle and moving, in one process (issue 28).

Builds the built-in cell's world as droid-sim does (:func:`droid.sim.world.build_world`) under a
cell name of its own (``simidle…``: its shared memory, ptys and loopback address are its own and
gone at exit), with arm1's servo and watchdog in the same process on the world's register map
(droid-servo's and droid-watchdog's stations and cores, at 500 Hz and 50 Hz of world time) and
an RDT client streaming from the F/T twin (droid-ft's part) and readers on the Brain's ends of
the sensors' serial lines (droid-remote's part: a pty nobody reads fills up and its writes slow
down).  With ``--home`` it homes arm1 first (HOME at 60 Hz: ~28 s of world time); the servo
holds the arm the same way homed or not.  It reports the process's resident size at the end
(VmRSS) and whether Pinocchio was imported (droid-sim's world should not: the compiled rigid-body
dynamics, droid.arm.rigid_body).  It measures the thread CPU time of ``World.advance``
(1 ms steps; the real-time loop's own wake-ups are not in it) over two phases:

* idle: the servo holding arm1 at rest, amplifiers on, the holder at rest (``--idle-s``);
* moving: arm1 jogged (JOG at 60 Hz, as droid-jog and the seam tracker's small corrections
  move it) with all six joints at 2-6 deg/s, 2 s out and 2 s back (``--moves`` pairs); the
  holder at rest.

With ``--plant`` the thread CPU of arm1's ``ReisPlant.advance`` alone is measured too, per phase
(a clock read around each call: ~1 us more a step in the World.advance figures, in both versions).

It also prints how many times a second droid-sim would wake for this world (1000 / its
``World.steps_per_wake``; an old tree without it woke at every step): the figures above are per
world step either way, the wake-ups' own cost (docs/benchmarks.md, issue 40) is per wake-up.

With ``--base DIR`` (an old checkout's top directory, e.g. ``git archive COMMIT | tar -x -C DIR``)
each version runs in a subprocess of its own (this file, ``PYTHONPATH`` = the checkout),
alternating ``--rounds`` times so both see the same load, and the figures are min and median
over the rounds; the two versions' digests of the world after homing, idle and moving (arm1's
register map and plant state, its truth record, the encoder cards' maps, the DSP board's record,
the twins' random generators and last readings) must be equal -- a speed-up that changes them
changes results.

Timing is measured here, never in tests (docs/benchmarks.md).  Usage::

    PYTHONPATH=. python bench/bench_world_step.py [--base DIR] [--rounds 3] [--idle-s 5] [--moves 1] [--home] [--plant] [--json]
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

HERE = Path(__file__).resolve()
DT_S = 0.001  # the world's step at the default cell's rate_hz [s]
SERVO_EVERY, WATCHDOG_EVERY, COMMAND_EVERY = 2, 20, 17  # world steps per servo / watchdog tick, ~60 Hz commands
JOG_DEG_PER_S = (3.0, 2.0, -2.5, 4.5, 3.5, 6.0)  # arm1's joint speeds while moving


def _digest(world) -> str:
    """One hash of what the world's twins hold (registers, state, generators, last readings)."""
    import numpy as np

    h = hashlib.sha256()
    arm = world.devices["arm1"]
    p = arm.plant
    h.update(bytes(p.regs))
    for k in ("_theta", "_omega", "_q", "_qd"):
        h.update(np.asarray(getattr(p, k)).tobytes())
    h.update(repr(p.time_s).encode())
    h.update(bytes(arm.door._region))
    gmf1 = world.devices["gmf1_karel"]
    h.update(np.asarray(gmf1.controller.q_deg).tobytes())
    for mv in gmf1.twin._mvs:
        h.update(bytes(mv))
    cam = world.devices["mvs_camera"]
    h.update(repr((cam.frames, cam.twin.rng.bit_generator.state)).encode())
    rec = cam.twin.writer._rec  # the DSP board's record, less the writer's pid
    h.update(np.asarray(rec["stripe"]).tobytes())
    h.update(repr((int(rec["frames"]), int(rec["sequence"]), int(rec["timestamp_ns"]))).encode())
    tool = world.devices["tool_sensor"].core
    h.update(repr((tool.last, tool.lines, tool.rng.bit_generator.state)).encode())
    ft = world.devices["ft_sensor"].twin
    h.update(np.asarray(ft.reading).tobytes())
    h.update(repr((ft.sent, ft.rng.bit_generator.state)).encode())
    return h.hexdigest()[:16]


def _vm_rss_kb() -> int:
    """This process's resident size [kB] (/proc/self/status VmRSS)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return -1  # pragma: no cover - not Linux


def worker(idle_s: float, moves: int, home: bool = False, plant: bool = False) -> dict:
    """Build, home, measure (one version: the droid package on PYTHONPATH)."""
    import socket

    import numpy as np

    from droid.brain.cell.cellfile import builtin_cell_path, load_cell
    from droid.sim.world import build_world
    from droid.subunits.ft.rdt import CMD_START_REALTIME, request
    from droid.subunits.reis.servo import ServoCore
    from droid.subunits.reis.servo_params import Mode, ServoParams
    from droid.subunits.reis.station import ServoStation, WatchdogStation
    from droid.subunits.reis.vme import VmeBus
    from droid.subunits.reis.watchdog import WatchdogCore

    tmp = Path(tempfile.mkdtemp(prefix="simidle"))
    name = f"simidle{uuid.uuid4().hex[:6]}"
    text = builtin_cell_path().read_text().replace('name = "sim"', f'name = "{name}"\nrun_dir = "{tmp}/run"', 1)
    (tmp / "cell.toml").write_text(text)
    cell = load_cell(tmp / "cell.toml")
    world = build_world(cell)
    bus = rdt = None
    ttys: list[int] = []
    try:
        bus = VmeBus.from_buffer(world.devices["arm1"].plant.regs)
        servo = ServoCore(ServoParams.from_robot(cell.subunit("arm1").robot))
        servo_st, watchdog_st = ServoStation(servo, bus), WatchdogStation(WatchdogCore(), bus)
        ft = world.devices["ft_sensor"]
        world.advance(DT_S)  # power up (droid-sim's first step): the F/T twin opens its sockets
        rdt = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rdt.setblocking(False)
        rdt.sendto(request(CMD_START_REALTIME), (ft.host, ft.port))
        ttys = [os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
                for path in (world.devices["mvs_cable"].b.path, world.devices["tool_sensor"].output.end.path)]
        clock = time.thread_time
        k = 0
        plant_cpu = [0.0, 0]  # --plant: arm1's ReisPlant.advance alone (CPU, calls) in the timed phases
        if plant:
            arm_plant = world.devices["arm1"].plant
            advance = arm_plant.advance

            def timed_advance(dt_s, _advance=advance, _acc=plant_cpu):
                t0 = clock()
                _advance(dt_s)
                _acc[0] += clock() - t0
                _acc[1] += 1
            arm_plant.advance = timed_advance

        def run(steps: int, command, timed: bool = False) -> float:
            nonlocal k
            cpu = 0.0
            for _ in range(steps):
                if timed:
                    t0 = clock()
                    world.advance(DT_S)
                    cpu += clock() - t0
                else:
                    world.advance(DT_S)
                k += 1
                if k % COMMAND_EVERY == 0 and command is not None:
                    servo.command(*command(k // COMMAND_EVERY))
                if k % WATCHDOG_EVERY == 0:
                    watchdog_st.observe(servo.tick, bool(servo.fault))
                    watchdog_st.cycle()
                if k % SERVO_EVERY == 0:
                    servo_st.cycle()
                    while True:  # droid-ft's reads: the records the twin sent
                        try:
                            rdt.recv(64)
                        except BlockingIOError:
                            break
                    for fd in ttys:  # the Brain's reads of the sensors' lines
                        try:
                            os.read(fd, 4096)
                        except BlockingIOError:
                            pass
            return cpu

        if home:
            homing = (Mode.HOME, (0,) * 6)
            for _ in range(120):
                run(500, lambda i: homing)
                if servo.homed:
                    break
        out = {"homed": bool(servo.homed), "homing_steps": k, "digests": [_digest(world)],
               # droid-sim's wake-ups a second for this world (World.steps_per_wake: an old tree woke every step)
               "wake_hz": 1.0 / DT_S / (world.steps_per_wake(1.0 / DT_S) if hasattr(world, "steps_per_wake") else 1)}
        hold = (Mode.JOG, (0,) * 6)
        run(1000, lambda i: hold)  # settle
        n_idle = int(round(idle_s / DT_S))
        plant_cpu[:] = [0.0, 0]
        out["idle_us"] = 1e6 * run(n_idle, lambda i: hold, timed=True) / n_idle
        out["plant_idle_us"] = 1e6 * plant_cpu[0] / plant_cpu[1] if plant_cpu[1] else None
        plant_cpu[:] = [0.0, 0]
        out["digests"].append(_digest(world))
        per_cmd = np.asarray(servo.params.joint_to_counts) @ np.asarray(JOG_DEG_PER_S) * COMMAND_EVERY * DT_S
        cpu, n_move = 0.0, 0
        for _ in range(moves):
            for sign in (1, -1):
                jog = (Mode.JOG, tuple(int(x) for x in np.rint(sign * per_cmd)))
                cpu += run(2000, lambda i: jog, timed=True)
                n_move += 2000
        out["moving_us"] = 1e6 * cpu / n_move if n_move else None
        out["plant_moving_us"] = 1e6 * plant_cpu[0] / plant_cpu[1] if plant_cpu[1] else None
        out["fault"] = int(servo.fault)
        out["amps_on"] = bool(world.devices["arm1"].plant.amps_on)
        out["digests"].append(_digest(world))
        out["rest_steps"] = getattr(world.devices["arm1"].plant, "rest_steps", None)
        out["vm_rss_kb"] = _vm_rss_kb()
        out["pinocchio"] = "pinocchio" in sys.modules
        return out
    finally:
        if rdt is not None:
            rdt.close()
        for fd in ttys:
            os.close(fd)
        if bus is not None:
            bus.close()
        world.close()
        shutil.rmtree(tmp, ignore_errors=True)


def run_worker(tree: Path, idle_s: float, moves: int, home: bool, plant: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    r = subprocess.run([sys.executable, str(HERE), "--worker", "--idle-s", str(idle_s), "--moves", str(moves)]
                       + (["--home"] if home else []) + (["--plant"] if plant else []),
                       env=env, cwd=str(tree), capture_output=True, text=True, timeout=1800)
    if r.returncode != 0:
        raise SystemExit(f"worker for {tree} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    from droid.cli import ArgumentParser, bounded_float, bounded_int

    ap = ArgumentParser(prog="bench_world_step", description=__doc__.split("\n")[0])
    ap.add_argument("--base", help="an old checkout's top directory: run it beside this one, alternating")
    ap.add_argument("--rounds", type=bounded_int(1, 50, "rounds"), default=3, help="runs of each version")
    ap.add_argument("--idle-s", type=bounded_float(0.1, 600.0, "s"), default=5.0, help="world seconds idle")
    ap.add_argument("--moves", type=bounded_int(1, 100, "moves"), default=1, help="pairs of out-and-back moves")
    ap.add_argument("--home", action="store_true", help="home arm1 first (~28 s of world time)")
    ap.add_argument("--plant", action="store_true", help="also time arm1's ReisPlant.advance alone")
    ap.add_argument("--worker", action="store_true", help=argparse_hidden())
    ap.add_argument("--json", action="store_true", help="one JSON object")
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.idle_s, args.moves, args.home, args.plant)))
        return 0
    trees = {"this": HERE.parent.parent}
    if args.base:
        base = Path(args.base).resolve()
        if not (base / "droid" / "sim" / "world.py").is_file():
            raise SystemExit(f"--base: {base}/droid/sim/world.py not found")
        trees = {"base": base, "this": HERE.parent.parent}
    runs: dict[str, list[dict]] = {n: [] for n in trees}
    for _ in range(args.rounds):
        for n, tree in trees.items():
            runs[n].append(run_worker(tree, args.idle_s, args.moves, args.home, args.plant))
    out = {"load_average": [round(x, 2) for x in os.getloadavg()], "rounds": args.rounds, "idle_s": args.idle_s,
           "moves": args.moves}
    for n, rs in runs.items():
        out[n] = {"homed": all(r["homed"] for r in rs), "rest_steps": rs[-1]["rest_steps"],
                  "vm_rss_kb": max(r["vm_rss_kb"] for r in rs), "pinocchio": any(r["pinocchio"] for r in rs),
                  "servo_fault": rs[-1]["fault"], "amps_on": rs[-1]["amps_on"], "wake_hz": rs[-1]["wake_hz"],
                  "digests": rs[0]["digests"], "digests_repeat": all(r["digests"] == rs[0]["digests"] for r in rs)}
        for phase in ("idle_us", "moving_us") + (("plant_idle_us", "plant_moving_us") if args.plant else ()):
            v = [r[phase] for r in rs]
            out[n][phase] = {"min": round(min(v), 1), "median": round(statistics.median(v), 1),
                             "all": [round(x, 1) for x in v]}
    if "base" in out:
        out["bit_identical"] = out["base"]["digests"] == out["this"]["digests"]
    if args.json:
        print(json.dumps(out))
        return 0
    for n in trees:
        v = out[n]
        print(f"{n:>5}: idle {v['idle_us']['min']:6.1f} min {v['idle_us']['median']:6.1f} median us/step, "
              f"moving {v['moving_us']['min']:6.1f} min {v['moving_us']['median']:6.1f} median us/step "
              f"(CPU of World.advance, {args.rounds} rounds; homed: {v['homed']}, servo fault {v['servo_fault']}, "
              f"amps on {v['amps_on']}, advances at rest {v['rest_steps']}; digests {v['digests']}; "
              f"droid-sim would wake {v['wake_hz']:g} times a second; "
              f"VmRSS {v['vm_rss_kb'] / 1024:.1f} MB, pinocchio imported: {v['pinocchio']})")
        if args.plant:
            print(f"{'':>5}  arm1's ReisPlant.advance alone: idle {v['plant_idle_us']['min']:6.1f} min "
                  f"{v['plant_idle_us']['median']:6.1f} median, moving {v['plant_moving_us']['min']:6.1f} min "
                  f"{v['plant_moving_us']['median']:6.1f} median us/step")
    if "bit_identical" in out:
        print(f"digests after homing, idle and moving equal: {out['bit_identical']}")
    print(f"load average {out['load_average']}")
    return 0


def argparse_hidden() -> str:
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    raise SystemExit(main())
