"""droid-guard's cost at 60 Hz in CPU-seconds (issue 41 target: <= 3 % of one core).

One GuardStation cycle -- read both arms' Brain Status records, the pass over the sim cell's
pairs now, at the next way-point and the horizon (the compiled pass where droid.guard.kernel
chooses it), the fault bits, the tick and overrides into both arms' Commands, its own Status
record -- on in-memory records, with the arms' joints varied every tick (nothing cached).  The
CPU time of N cycles (time.process_time) x 60 Hz is the share of one core the guard's own work
takes; the live program adds the heartbeat's ZeroMQ wake-up and its presence record.

``--still``: the arms at rest instead (the same joints every tick, as on an idle cell): the guard
then takes its last pass's figures again (GuardCore.step) and computes only the fall and the
verdict -- a separate figure, never the varied one.

    nice -n 10 .venv/bin/python bench/bench_guard_cpu.py [--n 6000] [--still]
"""
from __future__ import annotations

import time

import numpy as np

from droid.brain.db import layouts as L
from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.brain.db.shmdb import MemoryDatabase
from droid.cli import ArgumentParser, bounded_int
from droid.guard.station import GuardStation, guard_core
from droid.kinematics import load_robot


def main() -> None:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=bounded_int(10, 10**7), default=6000, help="cycles")
    ap.add_argument("--still", action="store_true", help="the arms at rest (the same joints every tick)")
    args = ap.parse_args()
    cell = load_cell(BUNDLED_CELLS / "sim.toml")
    core = guard_core(cell)
    arms, home = {}, {}
    for name in core.scene.arms:
        m = load_robot(cell.subunits[name].robot)
        arms[name] = (m.gearing, MemoryDatabase(f"{name}.status", L.ARM_STATUS_LAYOUT),
                      MemoryDatabase(f"{name}.ctrl_status", L.CTRL_STATUS_LAYOUT),
                      MemoryDatabase(f"{name}.command", L.ARM_COMMAND_LAYOUT))
        home[name] = np.rint(m.gearing.joints_to_counts(np.asarray(m.home_switch_deg, float)))
    station = GuardStation(core, arms, MemoryDatabase("guard.status", L.GUARD_STATUS_LAYOUT))
    rng = np.random.default_rng(2)
    wobble = {n: rng.integers(-3000, 3000, (args.n, 6)) * (0 if args.still else 1) for n in arms}  # a few deg about home
    for i in range(200):
        station.on_tick(i + 1)
    again0 = core.still_passes
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for i in range(args.n):
        for n, (_, st, *_rest) in arms.items():
            c = home[n] + wobble[n][i]
            st.update(encoder_pos=c, encoder_cmd=c)
        station.on_tick(1000 + i)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    per = cpu / args.n
    print(f"{'at rest' if args.still else 'varied'}: {core.still_passes - again0} of the timed passes taken again; "
          f"compiled pass: {core.scene.compiled is not None}; {args.n} cycles: {per * 1e6:.0f} us CPU a cycle "
          f"(wall {wall / args.n * 1e6:.0f} us); at 60 Hz {per * 60 * 100:.2f} % of one core "
          f"({per * 60:.4f} CPU-s a second); station cycle_max {station.cycle_max_us:.0f} us; trips {core.trips}")


if __name__ == "__main__":
    main()
