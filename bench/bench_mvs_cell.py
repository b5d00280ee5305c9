"""Cost of the MVS chain in the world and in lockstep (issue #6 phase 2).  Prints figures only.

    PYTHONPATH=. python bench/bench_mvs_cell.py [--seconds 40]

* one camera frame (render + DSP write) and one tool-sensor line [us];
* one second of the default cell's world (arms, camera, cable, tool sensor at
  its 200 Hz step) [ms of CPU];
* a lockstep trial of ``--seconds`` of virtual time with the camera chain or
  the ideal sensor, with and without the tool-tip sensor [s].
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from droid.brain.cell.cellfile import builtin_cell_path, load_cell
from droid.cli import ArgumentParser, duration_s
from droid.sim.lockstep import Scheduler
from droid.sim.mvs.lockstep import mvs_lockstep
from droid.sim.world import build_world


def per_call_us(fn, n=300) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def main() -> None:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=duration_s(), default=40.0, help="duration of the run [s]")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    text = builtin_cell_path().read_text().replace('name = "sim"', f'name = "benchmvs"\nrun_dir = "{tmp}/run"', 1)
    (tmp / "c.toml").write_text(text)
    cell = load_cell(tmp / "c.toml")
    world = build_world(cell)
    try:
        cam, tool = world.devices["mvs_camera"], world.devices["tool_sensor"]
        print(f"camera frame (render + board): {per_call_us(lambda: cam.frame(0)):.0f} us")
        print(f"tool-sensor line:              {per_call_us(tool.line):.0f} us")
        dt = 1.0 / float(cell.world["rate_hz"])
        t0 = time.process_time()
        for _ in range(int(round(10 / dt))):
            world.advance(dt)
        print(f"default world, 1 s at {1 / dt:g} Hz:  {(time.process_time() - t0) / 10 * 1e3:.0f} ms CPU")
        arms = {k: world.devices[k] for k in ("arm1", "gmf1")}
        devs = cell.world["devices"]
        cam_opts = {k: v for k, v in devs["mvs_camera"].items() if k not in ("type", "dsp")}
        tool_opts = {k: v for k, v in devs["tool_sensor"].items() if k not in ("type", "serial", "baud")}
        for ideal in (False, True):
            for with_tool in (False, True):
                sched = Scheduler(cell.heartbeat_hz)
                run = mvs_lockstep(sched, arms, cam_opts, tool_opts if with_tool else None, seed=1,
                                   ideal_sensor=ideal)
                t0 = time.process_time()
                sched.run_for(args.seconds)
                took = time.process_time() - t0
                run.close()
                what = ("ideal sensor" if ideal else "camera chain") + (" + tool" if with_tool else "")
                print(f"lockstep {args.seconds:g} s, {what:<21} {took:.2f} s CPU")
    finally:
        world.close()


if __name__ == "__main__":
    main()
