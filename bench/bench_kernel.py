"""The compiled kernel (issue 28 item 1): the candidates' start-up, locked memory and speed; python vs c.

Three measurements, each printed as a table (``--json``: one object):

1. **candidates** (``--candidates``): each in a fresh process -- the Python reference (numpy and
   plain floats, as droid/sim/reis/plant.py's ``_step_exact`` does it), the C extension
   (droid._kernel ``exact_step``, built by pip at install), numba (``@njit(cache=True)``, its own
   loops; ``--numba-python PY``: an interpreter that has numba, e.g. a scratch venv, since numba
   is not a project dependency) -- runs the plant's step core (DAC words -> torques -> the
   24x36 zero-order-hold product -> Coulomb friction and stiction -> encoders and switches
   written; Pinocchio's ``nonLinearEffects`` excluded: every candidate calls it the same way) on
   64 recorded plant states, cycled.  Start-up: the import and set-up of the candidate and its
   first call [ms] (numba: a cold cache and a warm one).  Memory: VmRSS and VmLck [MB] after
   ``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)`` (droid.brain.runtime.rt.lock_memory's call, after
   the imports) and 20 000 steps.  Speed: CPU us per step.
2. **cell** (always): two Reis cells in one process, the reference and ``kernel="c"`` (plant and
   servo PID), run alternately in 0.5 s chunks through homing and ``--moves`` pairs of 2 s moves:
   CPU us per plant advance and per servo cycle, and whether the two stay bit-identical.  With
   ``--rigid`` also on rigid drives with the compiled rigid body (droid-sim's world's plant: the
   compiled ``rigid_steps`` against ``_steps_rigid``; 2 ms advances, 4 substeps each).
3. **trial** (``--trials N``): bench/bench_seamtrack.py's trial (``--position``, ``--speed``, ideal
   sensor, seed 1) run N times per kernel in subprocesses with ``DROID_KERNEL`` python and c
   alternately: CPU seconds, x real time per CPU second, and whether the RMS figures agree.

Timing is measured here, never in tests.  Usage:
PYTHONPATH=. python bench/bench_kernel.py [--candidates] [--numba-python PY] [--moves N] [--trials N]
[--position i] [--speed 64] [--json]
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from droid.cli import run

ROOT = Path(__file__).resolve().parent.parent
MOVE_DEG = np.array([60.0, 45.0, -50.0, 90.0, 70.0, 120.0])
STEPS = 20_000
N_STATES = 64


# -- the candidates' step core, each on the same recorded inputs -----------------------------------
def record_states(path: str) -> None:
    """64 plant states from a cell homing and moving (the reference plant), with everything the
    step core reads: the step's matrices, the state, Pinocchio's C qd + g, the DAC words."""
    from droid.sim.reis.lockstep import ReisLockstep, constant_commander
    from droid.sim.reis.plant import ReisPlant, ReisPlantParams
    from droid.subunits.reis.servo import ServoCore
    from droid.subunits.reis.servo_params import Mode

    ls = ReisLockstep(ReisPlant(ReisPlantParams(), seed=1, kernel="python"), ServoCore(None, kernel="python"))
    p, rec = ls.plant, {k: [] for k in ("pg", "gm", "state", "tl", "dacs", "amps")}
    home = constant_commander(Mode.HOME)
    ls.run(0.05)
    while len(rec["pg"]) < N_STATES:
        ls.run(0.25, home, record=False)
        pg, gm, _ = p._discretise(0.002, p._q.tolist())
        rec["pg"].append(pg)
        rec["gm"].append(gm)
        rec["state"].append(np.concatenate((p._theta, p._omega, p._q, p._qd)))
        rec["tl"].append(p.body.bias(p._q, p._qd))  # Pinocchio's nonLinearEffects, copied
        rec["dacs"].append(np.frombuffer(bytes(p.regs[0x10:0x1C]), "<i2").astype(np.int64))
        rec["amps"].append(p._amps_on)
    np.savez(path, consts=p._consts, offset=p._enc_offset, **{k: np.array(v) for k, v in rec.items()})


def _python_core(data):
    """The reference's step core, as plant.py's ``_integrate`` (exact branch) and ``_step_exact``.

    A copy on purpose (the friction loop repeats ReisPlant._step_exact's): every candidate is
    timed on the same bare core, outside the plant object, on recorded states."""
    import math
    import struct
    k = data["consts"].tolist()
    tpd, tmax, tw0, tau_c0, brake, cpr, sw, side, bal = (k[0:6], k[6:12], k[12:18], k[18:24], k[24:30], k[30:36],
                                                          k[36:42], k[42:48], k[48])
    consts = list(zip(tpd, tmax, tw0))
    off = data["offset"].tolist()
    enc_s, u16 = struct.Struct("<6H"), struct.Struct("<H")
    regs = bytearray(64)
    view = memoryview(regs)
    z = np.empty(36)
    tau_c_arr, brake_arr = np.asarray(tau_c0), np.asarray(brake)

    def step(pg, g_m, st, tau_link, dacs, amps):
        theta, omega, q, qd = st[0:6], st[6:12], st[12:18], st[18:24]
        om, ql = omega.tolist(), q.tolist()
        drive, tcl = [], tau_c0
        if not amps:
            drive, tcl = [0.0] * 6, (tau_c_arr + brake_arr).tolist()
        for d, (kk, tm, a), w in zip(dacs if amps else (), consts, om):
            d = d if d > -2048 else -2048
            v = float(d if d < 2047 else 2047) * kk
            v = v if v > -tm else -tm
            v = v if v < tm else tm
            b = -tm - a * w
            v = v if v > b else b
            b = tm - a * w
            drive.append(v if v < b else b)
        nl = -tau_link[1] - bal * math.sin(ql[1])
        z[0:6], z[6:12], z[12:18], z[18:24], z[24:30] = theta, omega, q, qd, drive
        np.negative(tau_link, out=z[30:36])
        z[31] = nl
        free = pg @ z
        g_wd = np.diag(g_m[6:12]).tolist()
        keep = (False,) * 6
        kin = None
        if any(om):
            kin = [-tc if w > 0.0 else (tc if w < 0.0 else -0.0) for tc, w in zip(tcl, om)]
            x = free + g_m @ kin
            xl = x.tolist()
            keep = [a * w > 0.0 for a, w in zip(xl[6:12], om)]
        if not all(keep):
            w_end = free[6:12].tolist()
            fric, rest = [0.0] * 6, []
            for j, (tc, gw) in enumerate(zip(tcl, g_wd)):
                if keep[j]:
                    fric[j] = kin[j]
                    continue
                stick = -w_end[j] / gw
                if -tc <= stick <= tc:
                    fric[j] = stick
                    rest.append(j)
                else:
                    fric[j] = -tc if w_end[j] > 0.0 else tc
            x = free + g_m @ fric
            for j in rest:
                x[j] = theta[j]
                x[6 + j] = 0.0
            xl = x.tolist()
        enc = tuple([(math.floor(t * c) + o) % 65536 for t, c, o in zip(xl[0:6], cpr, off)])
        view[0:12] = enc_s.pack(*enc)
        bits = 0
        for j, (a, qj, s) in enumerate(zip(side, xl[12:18], sw)):
            if a * (qj - s) > 0.0:
                bits |= 1 << j
        view[0x20:0x22] = u16.pack(bits)
        return x
    return step


def _c_core(data):
    from droid import kernel
    k = kernel.load_compiled()
    consts, offset = data["consts"], data["offset"]
    regs = bytearray(64)
    x = np.empty(24)

    def step(pg, g_m, st, tau_link, dacs, amps):
        regs[0x10:0x1C] = dacs.astype("<i2").tobytes()
        k.exact_step(regs, consts, pg, g_m, st[0:6], st[6:12], st[12:18], st[18:24], tau_link, None, amps, False,
                     offset, x)
        return x
    return step


_NUMBA_SRC = '''
import math
import numpy as np
from numba import njit


@njit(cache=True)
def exact_step(regs, k, pg, gm, st, tl, dacs, amps, offset, x):
    z = np.empty(36)
    tau_c = np.empty(6)
    for j in range(6):
        v = 0.0
        if amps:
            tm = k[6 + j]; a = k[12 + j]; w = st[6 + j]
            d = float(min(max(dacs[j], -2048), 2047))
            v = d * k[j]
            v = v if v > -tm else -tm
            v = v if v < tm else tm
            b = -tm - a * w
            v = v if v > b else b
            b = tm - a * w
            v = v if v < b else b
            tau_c[j] = k[18 + j]
        else:
            tau_c[j] = k[18 + j] + k[24 + j]
        z[j] = st[j]; z[6 + j] = st[6 + j]; z[12 + j] = st[12 + j]; z[18 + j] = st[18 + j]
        z[24 + j] = v; z[30 + j] = -tl[j]
    z[31] = -tl[1] - k[48] * math.sin(st[13])
    free = np.zeros(24)
    for i in range(24):
        s = 0.0
        for j in range(36):
            s += pg[i, j] * z[j]
        free[i] = s
    keep = np.zeros(6, np.bool_)
    kin = np.zeros(6)
    moving = False
    for j in range(6):
        moving = moving or st[6 + j] != 0.0
    alln = False
    if moving:
        for j in range(6):
            w = st[6 + j]
            kin[j] = -tau_c[j] if w > 0.0 else (tau_c[j] if w < 0.0 else -0.0)
        for i in range(24):
            s = 0.0
            for j in range(6):
                s += gm[i, j] * kin[j]
            x[i] = free[i] + s
        alln = True
        for j in range(6):
            keep[j] = x[6 + j] * st[6 + j] > 0.0
            alln = alln and keep[j]
    if not alln:
        fric = np.zeros(6)
        rest = np.zeros(6, np.bool_)
        for j in range(6):
            tc = tau_c[j]
            if keep[j]:
                fric[j] = kin[j]
                continue
            stick = -free[6 + j] / gm[6 + j, j]
            if -tc <= stick and stick <= tc:
                fric[j] = stick
                rest[j] = True
            else:
                fric[j] = -tc if free[6 + j] > 0.0 else tc
        for i in range(24):
            s = 0.0
            for j in range(6):
                s += gm[i, j] * fric[j]
            x[i] = free[i] + s
        for j in range(6):
            if rest[j]:
                x[j] = st[j]
                x[6 + j] = 0.0
    bits = 0
    for j in range(6):
        v = (int(math.floor(x[j] * k[30 + j])) + offset[j]) % 65536
        regs[2 * j] = v & 0xFF
        regs[2 * j + 1] = v >> 8
        if k[42 + j] * (x[12 + j] - k[36 + j]) > 0.0:
            bits |= 1 << j
    regs[0x20] = bits
    return x
'''


def _numba_core(data, cache_dir: str):
    sys.path.insert(0, cache_dir)
    src = Path(cache_dir) / "droid_numba_step.py"
    if not src.exists():
        src.write_text(_NUMBA_SRC)
    import droid_numba_step as m
    consts, offset = data["consts"], data["offset"]
    regs = np.zeros(64, np.uint8)
    x = np.empty(24)

    def step(pg, g_m, st, tau_link, dacs, amps):
        return m.exact_step(regs, consts, pg, g_m, st, tau_link, dacs, amps, offset, x)
    return step


def _status_mb(field: str) -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def worker(candidate: str, data_path: str, cache_dir: str) -> dict:
    """One candidate in this (fresh) process: start-up, locked memory, speed."""
    import ctypes
    t0 = time.perf_counter()
    data = dict(np.load(data_path))
    make = {"python": _python_core, "c": _c_core, "numba": lambda d: _numba_core(d, cache_dir)}[candidate]
    step = make(data)
    rows = [(data["pg"][i], data["gm"][i], data["state"][i], data["tl"][i], data["dacs"][i], bool(data["amps"][i]))
            for i in range(len(data["pg"]))]
    first = step(*rows[0]).copy()
    startup_ms = 1e3 * (time.perf_counter() - t0)
    libc = ctypes.CDLL(None, use_errno=True)
    locked = libc.mlockall(1 | 2 | 4) == 0  # MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT
    n = len(rows)
    c0 = time.process_time()
    for i in range(STEPS):
        step(*rows[i % n])
    us = 1e6 * (time.process_time() - c0) / STEPS
    return {"candidate": candidate, "startup_ms": round(startup_ms, 1), "locked": locked,
            "rss_mb": round(_status_mb("VmRSS"), 1), "locked_mb": round(_status_mb("VmLck"), 1),
            "us_per_step": round(us, 2), "first_x": first.tolist()}


def candidates(numba_python: str | None) -> list[dict]:
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "states.npz")
        record_states(data)
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        runs = [("python", sys.executable), ("c", sys.executable)]
        if numba_python:
            runs += [("numba", numba_python), ("numba", numba_python)]  # a cold cache, then a warm one
        for i, (cand, py) in enumerate(runs):
            r = subprocess.run([py, __file__, "--worker", cand, "--data", data, "--cache-dir", tmp], env=env,
                               capture_output=True, text=True, timeout=600)
            if r.returncode != 0:
                raise RuntimeError(f"{cand}: {r.stderr[-2000:]}")
            res = json.loads(r.stdout.splitlines()[-1])
            if cand == "numba":
                res["candidate"] = "numba (cold cache)" if i == len(runs) - 2 else "numba (warm cache)"
            out.append(res)
    ref = out[0]["first_x"]
    for r in out:
        r["max_abs_diff_first_step"] = float(np.max(np.abs(np.array(r.pop("first_x")) - np.array(ref))))
    return out


# -- two cells side by side ----------------------------------------------------------------------
def cells(moves: int, rigid: bool = False) -> dict:
    from droid.sim.reis.lockstep import ReisLockstep, drive_side_by_side, plants_same_bits
    from droid.sim.reis.plant import ReisPlant, ReisPlantParams
    from droid.subunits.reis.servo import ServoCore

    cs, acc = {}, {}
    params, kw = (ReisPlantParams(compliance=False), {"rigid_body": "kernel"}) if rigid else (ReisPlantParams(), {})
    for k in ("python", "c"):
        ls = cs[k] = ReisLockstep(ReisPlant(params, seed=1, kernel=k, **kw), ServoCore(None, kernel=k))
        a = acc[k] = {"plant": [0.0, 0], "servo": [0.0, 0]}
        for part, owner, attr in (("plant", ls.plant, "advance"), ("servo", ls.servo_station, "cycle")):
            fn = getattr(owner, attr)

            def timed(*args, _fn=fn, _a=a[part], _clock=time.thread_time):
                t0 = _clock()
                r = _fn(*args)
                _a[0] += _clock() - t0
                _a[1] += 1
                return r
            setattr(owner, attr, timed)
    differ = [0]

    def compare() -> None:
        differ[0] += not plants_same_bits(cs["python"].plant, cs["c"].plant)
    drive_side_by_side(cs, MOVE_DEG, moves, compare)
    return {"sim_s": round(cs["c"].time_s, 2),
            "bit_identical": differ[0] == 0 and plants_same_bits(cs["python"].plant, cs["c"].plant),
            **{f"{k}_{part}_us": round(1e6 * v[0] / max(1, v[1]), 1) for k, a in acc.items() for part, v in a.items()}}


# -- whole trials ----------------------------------------------------------------------------------
def trials(n: int, position: str, speed: float) -> list[dict]:
    out = []
    for i in range(n):
        for k in ("python", "c"):
            env = dict(os.environ, DROID_KERNEL=k, PYTHONPATH=str(ROOT))
            r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_seamtrack.py"), "--positions", position,
                                "--speeds", f"{speed:g}", "--sensors", "ideal", "--json"], env=env,
                               capture_output=True, text=True, timeout=1800)
            if r.returncode != 0:
                raise RuntimeError(r.stderr[-2000:])
            d = json.loads(r.stdout.splitlines()[0])
            out.append({"kernel": k, "run": i, "sim_s": d["sim_s"], "prep_s": d["prep_s"], "cpu_s": d["cpu_s"],
                        "trial_x_per_cpu_s": round(d["sim_s"] / d["cpu_s"], 1), "all_x_per_cpu_s": d["cpu_x"],
                        "rms_lateral_mm": d["rms_lateral_mm"], "rms_depth_mm": d["rms_depth_mm"],
                        "load": round(os.getloadavg()[0], 2)})
    return out


@run
def main(argv=None) -> int:
    import argparse

    from droid.brain.cell.cell_layout import load_layout
    from droid.cli import ArgumentParser, bounded_float, bounded_int

    parser = ArgumentParser(prog="bench_kernel", description=__doc__.split("\n")[0])
    parser.add_argument("--candidates", action="store_true", help="measure the candidates in fresh processes")
    parser.add_argument("--numba-python", help="an interpreter with numba (the numba candidate; else skipped)")
    parser.add_argument("--moves", type=bounded_int(0, 100, "moves"), default=2,
                        help="pairs of out-and-back moves in the cell comparison")
    parser.add_argument("--rigid", action="store_true",
                        help="also the cell comparison on rigid drives with the compiled rigid body (droid-sim's plant)")
    parser.add_argument("--trials", type=bounded_int(0, 20, "trials"), default=0,
                        help="trial runs per kernel (alternating)")
    parser.add_argument("--position", default="i", choices=sorted(load_layout().positions),
                        help="the trial's start position (thesis §6.1)")
    parser.add_argument("--speed", type=bounded_float(0.1, 200.0, "mm/s"), default=64.0,
                        help="the trial's speed [mm/s]")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--data", help=argparse.SUPPRESS)
    parser.add_argument("--cache-dir", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker, args.data, args.cache_dir)))
        return 0
    res = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "cpus": os.cpu_count(),
           "load_start": round(os.getloadavg()[0], 2)}
    if args.candidates:
        res["candidates"] = candidates(args.numba_python)
    res["cells"] = cells(args.moves)
    if args.rigid:
        res["cells_rigid"] = cells(args.moves, rigid=True)
    if args.trials:
        res["trials"] = trials(args.trials, args.position, args.speed)
    res["load_end"] = round(os.getloadavg()[0], 2)
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"{res['date']}, {res['cpus']} CPUs, load {res['load_start']} -> {res['load_end']}")
    for r in res.get("candidates", []):
        print(f"{r['candidate']:>20}: start-up {r['startup_ms']:7.1f} ms, RSS {r['rss_mb']:6.1f} MB, locked "
              f"{r['locked_mb']:6.1f} MB, {r['us_per_step']:6.2f} us/step, first step max |diff| "
              f"{r['max_abs_diff_first_step']:.3g}")
    for name in ("cells", "cells_rigid"):
        c = res.get(name)
        if c is not None:
            print(f"{name} ({c['sim_s']} s simulated, bit-identical: {c['bit_identical']}): plant {c['python_plant_us']} "
                  f"-> {c['c_plant_us']} us/advance, servo cycle {c['python_servo_us']} -> {c['c_servo_us']} us")
    for t in res.get("trials", []):
        print(f"trial {args.position}/{args.speed:g} {t['kernel']:>6}: {t['cpu_s']:.3f} CPU s, trial "
              f"{t['trial_x_per_cpu_s']}x, all {t['all_x_per_cpu_s']}x per CPU s, RMS {t['rms_lateral_mm']} / "
              f"{t['rms_depth_mm']} mm (load {t['load']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
