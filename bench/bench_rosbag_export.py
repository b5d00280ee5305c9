"""Time to export a 10-minute recording of the default cell as a ROS 2 bag (issue 29 item 3; target <= 20 s).

    PYTHONPATH=. python bench/bench_rosbag_export.py [--minutes 10] [--mcap FILE] [--keep DIR]

The recording is synthetic but realistic, and made with the recorder's own
writer: the built-in sim cell's metadata and scene (arm1, gmf1, mvs, tool, joy),
and ``CellRecorder`` + ``RecordingWriter`` fed records at 60 Hz ticks -- the
records droid-record writes, with varied values: both arms follow smooth joint
paths (encoder counts through each robot's gearing, the Status pose by forward
kinematics: a slow sweep with a small wobble), each sends a command every 2 ticks, the lead sensor reads at 30 Hz
with an invalid stretch every 10 s, the tool-tip sensor reads every tick, the
joystick moves, program health every 12 ticks.  (Lockstep would be realistic
too, but it runs at about real time on this VM: 10 minutes per file.)  Making
it is not timed.  Then ``droid-replay FILE --export rosbag2 DIR`` runs as its own
process and its wall time (and user + system CPU) is printed with the load.

``--mcap FILE``: reuse (or make once and keep) that recording.  ``--keep DIR``:
keep the bag there.  Prints figures only; the verdict is the reader's
(docs/benchmarks.md).
"""
from __future__ import annotations

import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from droid.brain.cell.cellfile import load_cell  # noqa: E402
from droid.brain.db.databases import brain_layouts  # noqa: E402
from droid.brain.db.layouts import CARTSPACE, HOMED, NORMAL_MODE, new_record  # noqa: E402
from droid.cli import ArgumentParser, bounded_float  # noqa: E402
from droid.kinematics import load_robot  # noqa: E402
from droid.kinematics.transforms import rotz  # noqa: E402
from droid.observe.mcapfile import RecordingWriter, cell_meta  # noqa: E402
from droid.observe.record import CellRecorder  # noqa: E402
from droid.observe.scene import scene_meta  # noqa: E402

HZ = 60.0


def make_recording(path: str, minutes: float) -> int:
    """Write a synthetic recording of the default cell; returns its ticks."""
    cell = load_cell(None)
    meta = cell_meta(cell, "live", scene_meta(cell))
    core = CellRecorder(RecordingWriter(path, meta))
    recs = {}
    for sub in cell.subunits.values():
        for area, lay in brain_layouts(sub).items():
            r = new_record(lay)
            recs[(sub.name, area)] = (lay, r)
    arms = {name: load_robot(cell.subunit(name).robot) for name in ("arm1", "gmf1")}
    # a slow sweep along the seam (one period: the whole recording) with a small fast wobble, as a
    # tracking arm moves; the seam map (one point per mm the reading moves) stays a few thousand points
    q0 = {"arm1": np.array([0.0, 10.0, -20.0, 0.0, 40.0, 0.0]), "gmf1": np.array([0.0, 5.0, -5.0, 0.0, -30.0, 0.0])}
    amp = {"arm1": np.array([8.0, 3.0, 3.0, 2.0, 2.0, 5.0]), "gmf1": np.array([3.0, 1.0, 1.0, 2.0, 2.0, 4.0])}
    wobble_deg, wobble_s = np.array([0.05, 0.03, 0.03, 0.1, 0.1, 0.2]), np.array([2.1, 1.7, 2.9, 1.3, 3.1, 2.3])
    period = minutes * 60.0  # s
    rows = [{"name": p, "key": p.replace(" ", "."), "host": "brain", "pid": 1000 + k, "alive": True, "state": "ready",
             "live": True, "last_tick": 0, "age_s": 0.01, "cycles": 0, "overruns": 0, "bad_frames": 0}
            for k, p in enumerate(["droid-heartbeat", "droid-remote arm1", "droid-remote gmf1", "droid-servo arm1",
                                   "droid-planner arm1", "droid-mvs mvs"])]  # droid-cell status --json rows
    n = int(minutes * 60 * HZ)
    t0_ns = time.time_ns()
    for i in range(n):
        t = i / HZ
        t_ns = t0_ns + round(i * 1e9 / HZ)
        tick = 1000 + i
        records = []
        for (name, area), (lay, r) in recs.items():
            if area == "status":
                r["tick"] = tick
                r["updated_ns"] = t_ns
            if name in arms:
                q = (q0[name] + amp[name] * np.sin(2 * math.pi * t / period + (0.3 if name == "gmf1" else 0.0))
                     + wobble_deg * np.sin(2 * math.pi * t / wobble_s))
                counts = arms[name].gearing.joints_to_counts_int(q)
                T = arms[name].fk(q)
                r["x"], r["y"], r["z"] = T[:3, 3]
                r["R"] = T[:3, :3]
                if area == "status":
                    r["encoder_pos"] = counts
                    r["encoder_cmd"] = counts
                    r["homed"] = HOMED
                    r["cmd_mode"], r["coord"] = NORMAL_MODE, CARTSPACE
                    r["busy"] = i % 2
                    r["cmd_id"] = i // 2
                elif i % 2 == 0:  # a command every cycle (2 ticks)
                    r["encoder_pos"] = counts
                    r["cart_time_count"] = 2
                    r["cmd_id"] = i // 2 + 1
                    r["cmd_mode"], r["coord"] = NORMAL_MODE, CARTSPACE
            elif name == "mvs":
                if i % 2 == 0:  # 30 Hz readings; invalid for 1 s every 10 s
                    r["updated_ns"] = t_ns
                    r["homed"] = 1 if (t % 10.0) < 1.0 else 0
                    r["x"] = 150.0 + 5.0 * math.sin(t / 3.0)
                    r["y"] = 2.0 * math.sin(t / 1.7)
                    r["R"] = rotz(0.05 * math.sin(t / 5.0))[:3, :3]
                    r["valid_count" if r["homed"] == 0 else "invalid_count"] += 1
                else:
                    r["tick"] = tick - 1
                    r["updated_ns"] = t_ns - round(1e9 / HZ)
            elif name == "tool":
                r["x"] = 0.3 * math.sin(t / 2.3)
                r["y"] = 0.5 * math.sin(t / 1.1)
            elif lay.name == "joystick_status":
                r["valid"], r["n_axes"], r["n_buttons"] = 1, 2, 8
                r["axes"][:2] = (math.sin(t / 4.0), math.cos(t / 6.0))
                r["buttons"][:8] = [(i // 60 + k) % 5 == 0 for k in range(8)]
                r["events"] += 1
            records.append((name, area, lay, r))
        health = {"programs": rows, "heartbeat": {"lateness_max_ns": 90000, "overruns": 0, "last_tick": tick}} \
            if core.wants_health() else None
        core.sample(tick, t_ns, records, health_row=health)
    core.close()
    return n


def main(argv=None) -> int:
    ap = ArgumentParser("bench_rosbag_export", description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=bounded_float(0.1, 60.0, "min"), default=10.0, help="recording length (default 10)")
    ap.add_argument("--mcap", default=None, help="the recording to export (made first if missing)")
    ap.add_argument("--keep", default=None, metavar="DIR", help="keep the bag in DIR (default: a temporary one)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="droid-bench-bag-") as tmp:
        mcap = args.mcap or str(Path(tmp) / "cell.mcap")
        if not os.path.exists(mcap):
            t = time.perf_counter()
            n = make_recording(mcap, args.minutes)
            print(f"made {mcap}: {n} ticks ({args.minutes:g} min at {HZ:g} Hz), "
                  f"{os.path.getsize(mcap) / 1e6:.1f} MB in {time.perf_counter() - t:.1f} s")
        bag = args.keep or str(Path(tmp) / "bag")
        load = os.getloadavg()
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-m", "droid.observe.replay", mcap, "--export", "rosbag2", bag],
                             capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if out.returncode != 0:
            print(out.stderr, file=sys.stderr)
            return 1
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        size = sum(f.stat().st_size for f in Path(bag).iterdir())
        print(out.stdout, end="")
        print(f"export: {wall:.1f} s wall (target <= 20 s), {cpu:.1f} s CPU, bag {size / 1e6:.1f} MB; "
              f"load average before {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}, after "
              f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}; {os.cpu_count()} CPUs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
