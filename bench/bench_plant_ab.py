"""Two versions of the Reis plant twin side by side in one process: CPU per advance and bit-identity.

Loads ``droid/sim/reis/plant.py`` from an old checkout (``--base DIR``, e.g. made with
``git archive COMMIT | tar -x -C DIR``) beside this checkout's, puts each behind its own
lockstep servo and watchdog (droid.sim.reis.lockstep.ReisLockstep, seed 1), and runs the two
in alternating 0.5 s chunks -- homing, then ``--moves`` pairs of 2 s minimum-jerk moves of all
six joints (60-120 deg) out and back, then ``--hold-s`` of the servo holding the last target
(the idle cell) -- so both see the same load.  Prints the CPU time [us] per plant advance of
each (thread time around each advance) per phase and whether the two plants' registers and
states are bit-identical after every chunk.  ``--rigid``: the plant on rigid drives
(``compliance=False``, droid-sim's default cell) instead of the compliant, exact one.  A speed-up that is not
bit-identical changes the trial results (bench/fp_order_trial.py, docs/benchmarks.md).

Timing is measured here, never in tests.  Usage:
PYTHONPATH=. python bench/bench_plant_ab.py --base DIR [--moves N] [--hold-s S] [--rigid] [--json]
"""
from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

from droid.cli import ArgumentParser, BadInput, bounded_float, bounded_int, run
from droid.sim.reis.lockstep import ReisLockstep, drive_side_by_side, plants_same_bits
from droid.subunits.reis.servo import ServoCore

MOVE_DEG = np.array([60.0, 45.0, -50.0, 90.0, 70.0, 120.0])
HERE = Path(__file__).resolve().parent.parent / "droid" / "sim" / "reis" / "plant.py"


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def bench(base: Path, moves: int, hold_s: float = 5.0, rigid: bool = False) -> dict:
    mods = {"base": _load(base, "plant_base"), "this": _load(HERE, "plant_this")}
    cells, acc = {}, {}
    for name, mod in mods.items():
        params = mod.ReisPlantParams(compliance=False) if rigid else mod.ReisPlantParams()
        ls = ReisLockstep(mod.ReisPlant(params, seed=1), ServoCore(None))
        a = acc[name] = [0.0, 0]
        advance = ls.plant.advance

        def timed(dt, _adv=advance, _a=a, _clock=time.thread_time):
            t0 = _clock()
            _adv(dt)
            _a[0] += _clock() - t0
            _a[1] += 1
        ls.plant.advance = timed
        cells[name] = ls

    pa, pb = cells["base"].plant, cells["this"].plant
    differ = [0, 0]  # chunks compared, chunks whose registers or state differed

    def compare():
        differ[0] += 1
        differ[1] += not plants_same_bits(pa, pb)
    homed: dict = {}

    def mark_homed() -> None:
        homed.update({n: (tuple(a), cells[n].servo.homed) for n, a in acc.items()})
    cmds = drive_side_by_side(cells, MOVE_DEG, moves, compare, max_homing_chunks=80, on_homed=mark_homed)
    moved = {n: tuple(a) for n, a in acc.items()}
    for _ in range(int(round(hold_s / 0.5))):  # the last commander holds its target: the idle cell
        for n in ("base", "this"):
            cells[n].run(0.5, cmds[n], record=False)
        compare()
    out = {"base": str(base), "rigid": rigid, "sim_s": round(cells["this"].time_s, 3),
           "bit_identical": plants_same_bits(pa, pb) and differ[1] == 0, "chunks_compared": differ[0],
           "chunks_differing": differ[1]}
    for n, a in acc.items():
        (h_s, h_n), ok = homed[n]
        m_s, m_n = moved[n]
        out[n] = {"homed": bool(ok), "homing_us_per_advance": round(1e6 * h_s / h_n, 1),
                  "moves_us_per_advance": round(1e6 * (m_s - h_s) / max(1, m_n - h_n), 1),
                  "hold_us_per_advance": round(1e6 * (a[0] - m_s) / max(1, a[1] - m_n), 1),
                  "rest_steps": getattr(cells[n].plant, "rest_steps", None)}
    return out


@run
def main(argv=None) -> int:
    parser = ArgumentParser(prog="bench_plant_ab", description=__doc__.split("\n")[0])
    parser.add_argument("--base", required=True, help="an old checkout's top directory (holds droid/sim/reis/plant.py)")
    parser.add_argument("--moves", type=bounded_int(1, 1000, "moves"), default=2, help="pairs of out-and-back moves")
    parser.add_argument("--hold-s", type=bounded_float(0.0, 600.0, "hold"), default=5.0,
                        help="seconds of the servo holding its last target after the moves (the idle cell)")
    parser.add_argument("--rigid", action="store_true", help="rigid drives (compliance=False; droid-sim's default cell)")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args(argv)
    base = Path(args.base) / "droid" / "sim" / "reis" / "plant.py"
    if not base.is_file():
        raise BadInput(f"--base: {base} not found")
    r = bench(base, args.moves, args.hold_s, args.rigid)
    # Alike in shape only to other benches' output: --json one object, else this bench's own table.
    if args.json:
        print(json.dumps(r))
        return 0
    for n in ("base", "this"):
        v = r[n]
        print(f"{n:>5}: homing {v['homing_us_per_advance']:6.1f} us/advance, moves {v['moves_us_per_advance']:6.1f} "
              f"us/advance, hold {v['hold_us_per_advance']:6.1f} us/advance (homed: {v['homed']}, "
              f"advances at rest not integrated: {v['rest_steps']})")
    print(f"{'rigid' if r['rigid'] else 'compliant'} drives, after {r['sim_s']} s simulated, registers and state "
          f"bit-identical after each of {r['chunks_compared']} chunks: {r['bit_identical']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
