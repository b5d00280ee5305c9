"""How much a seam trial moves when the plant's floating-point summation order changes (issue 13 item 6).

Runs one trial twice -- as it is, and with the Reis plant's two per-step matrix products
(``[Phi | Gamma] @ [x; tau]``, 24x36, and the friction response, 24x6) stored in Fortran
order, so that BLAS sums the same products in another order (what a compiled plant step
with its own loops, or another BLAS, would do) -- and prints the tool errors' RMS after
s = 150 mm, the simulated trial length and a hash of each log.  Nothing else changes.

The answer decides whether the plant may be compiled (numba, C) with a result tolerance:
docs/benchmarks.md, "Lockstep speed, session 6".  It measures the Python reference
(``DROID_KERNEL=python``, the default): the compiled kernel takes C-ordered matrices only and
refuses the Fortran-ordered ones (BufferError).  Usage:
PYTHONPATH=. python bench/fp_order_trial.py [--position i] [--speed 64] [--seed 1] [--json]
"""
from __future__ import annotations

import hashlib
import json
import math
import pickle

import numpy as np

from droid.cli import ArgumentParser, BadInput, bounded_float, run, seed_int
from droid.experiments import trial
from droid.sim.reis import plant as reis_plant
from droid.tasks.seam.params import MAX_SPEED_MM_S
from droid.brain.cell.cell_layout import load_layout

AFTER_MM = 150.0  # as bench/bench_seamtrack.py


def _run(position: str, speed: float, seed: int) -> dict:
    layout_pos = load_layout().position(position)
    cfg = trial.TrialConfig(f"{position}-{speed:g}-ideal", position, speed,
                            workpiece=layout_pos.workpiece or "step_input", sensor="ideal", seed=seed, arm="full")
    r = trial.run_trial(cfg)
    s = r.column("s_mm")
    after = s > AFTER_MM
    rms = (lambda v: float(np.sqrt(np.nanmean(v ** 2))) if np.isfinite(v).any() else math.nan)
    blob = pickle.dumps((r.rows, r.stop_reason, r.sim_s))
    return {"sim_s": round(r.sim_s, 3), "stop": r.stop_reason,
            "rms_lateral_mm": rms(r.column("tool_lateral_mm")[after]),
            "rms_depth_mm": rms(r.column("tool_depth_mm")[after]), "log_md5": hashlib.md5(blob).hexdigest()}


@run
def main(argv=None) -> int:
    parser = ArgumentParser(prog="fp_order_trial", description=__doc__.split("\n")[0])
    parser.add_argument("--position", default="i", help="start position (i, iii, vii, ...)")
    parser.add_argument("--speed", type=bounded_float(0.0, MAX_SPEED_MM_S, "mm/s", lo_open=True), default=64.0,
                        help="tool speed [mm/s]")
    parser.add_argument("--seed", type=seed_int, default=1, help="random seed")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args(argv)
    try:
        load_layout().position(args.position)
    except (KeyError, ValueError) as e:
        raise BadInput(f"--position: {e}") from None
    out = {"position": args.position, "speed_mm_s": args.speed, "seed": args.seed}
    out["as_is"] = _run(args.position, args.speed, args.seed)
    original = reis_plant.ReisPlant._discretise

    def fortran_order(self, *a):
        pg, g_m, g_wd = original(self, *a)
        return np.asfortranarray(pg), np.asfortranarray(g_m), g_wd

    reis_plant.ReisPlant._discretise = fortran_order
    try:
        out["other_order"] = _run(args.position, args.speed, args.seed)
    finally:
        reis_plant.ReisPlant._discretise = original
    out["delta_rms_lateral_mm"] = out["other_order"]["rms_lateral_mm"] - out["as_is"]["rms_lateral_mm"]
    out["delta_rms_depth_mm"] = out["other_order"]["rms_depth_mm"] - out["as_is"]["rms_depth_mm"]
    # Alike in shape only to other benches' output: --json one object, else this trial's own table.
    if args.json:
        print(json.dumps(out))
        return 0
    for k in ("as_is", "other_order"):
        v = out[k]
        print(f"{k:>12}: {v['sim_s']:7.1f} s simulated, {v['stop']}, lateral RMS {v['rms_lateral_mm']:.6f} mm, "
              f"depth RMS {v['rms_depth_mm']:.6f} mm, log {v['log_md5'][:12]}")
    print(f"{'difference':>12}: lateral {out['delta_rms_lateral_mm']:+.6f} mm, depth {out['delta_rms_depth_mm']:+.6f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
