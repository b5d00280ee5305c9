"""droid-ros2 on a live cell (issue 42): JointState latency and delivery, and droid-ros2's CPU.

    PYTHONPATH=. python bench/bench_ros2.py --cell CELL.toml [--seconds 60] [--domain N]

Needs a cell that is up (``droid-cell up``; the default sim cell with its heartbeat) and the
``ros2`` extra.  It starts ``droid-ros2`` (commands off) on the cell, and a plain rclpy node
(tests/ros2/plain_probe.py ``stream``: rclpy and sensor_msgs only, no DROID code) that takes every
``/<arm>/joint_states`` for ``--seconds`` and records its arrival (CLOCK_REALTIME) beside the
message's stamp, which droid-ros2 sets to the Status refresh (``updated_ns``, CLOCK_MONOTONIC,
moved to the wall clock).  It prints

* latency from the Brain's Status refresh to the independent node's callback: p50 / p99 / max [ms]
  per arm;
* delivery: messages a second per arm (the heartbeat rate is the most there can be), and the worst
  whole second;
* droid-ros2's CPU (user + system, /proc/PID/stat) over the same window, as % of one core;
* the floor beside them: the same subscriber on a plain rclpy publisher of JointState at the
  heartbeat rate stamped at publishing (tests/ros2/plain_probe.py ``floor-pub``), and
  ``cyclictest``'s wake-up latency (bench/floor.py) when it is installed.

Loopback only (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST); the domain is ``--domain`` (default a
random one in 20..101, below the ids whose ports fall in Linux's ephemeral range).  Prints figures
only; the verdict is the reader's (targets: p99 beside the floor, >= 59 of 60 messages a second per
arm, <= 5 % of one core; docs/ros2.md).
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from droid.cli import ArgumentParser, bounded_int, duration_s  # noqa: E402

PROBE = ROOT / "tests" / "ros2" / "plain_probe.py"


def cpu_ticks(pid: int) -> int:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])  # utime + stime [clock ticks]


def figures(rows: list, hz: float) -> str:
    if not rows:
        return "no message"
    a = np.asarray([r[0] for r in rows], float)
    lat_ms = (a - np.asarray([r[1] for r in rows], float)) / 1e6
    secs = np.floor((a - a[0]) / 1e9).astype(int)
    whole = np.bincount(secs)[:-1] if secs[-1] > 0 else np.bincount(secs)
    span = (a[-1] - a[0]) / 1e9
    rate = (len(a) - 1) / span if span > 0 else float("nan")
    return (f"latency p50 {np.percentile(lat_ms, 50):.2f} ms, p99 {np.percentile(lat_ms, 99):.2f} ms, "
            f"max {lat_ms.max():.2f} ms; {rate:.2f} msg/s (heartbeat {hz:g} Hz), worst whole second "
            f"{int(whole.min()) if len(whole) else len(a)}; {len(a)} messages")


def main() -> int:
    ap = ArgumentParser(description="droid-ros2 on a live cell: JointState latency, delivery and CPU.")
    ap.add_argument("--cell", required=True, metavar="FILE", help="the cell file of a cell that is up")
    ap.add_argument("--seconds", type=duration_s(3600.0), default=60.0, metavar="S")
    ap.add_argument("--domain", type=bounded_int(1, 232), default=None, metavar="N")
    args = ap.parse_args()
    from bench.floor import cyclictest_floor, when_and_load
    from droid.brain.cell.cellfile import load_cell

    cell = load_cell(args.cell)
    arms = [s.name for s in cell.subunits.values() if s.is_arm]
    domain = args.domain or random.randint(20, 101)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    print(f"bench_ros2: {when_and_load()}; cell {cell.name}, arms {', '.join(arms)}, domain {domain}")
    node = subprocess.Popen([sys.executable, "-m", "droid.ros2.node", "--cell", args.cell], cwd=ROOT, env=env,
                            stderr=subprocess.PIPE, text=True)
    out = Path(tempfile.mkdtemp()) / "stream.json"
    try:
        time.sleep(2.0)
        c0, t0 = cpu_ticks(node.pid), time.monotonic()
        probe = subprocess.run([sys.executable, str(PROBE), "stream", str(out), str(args.seconds),
                                *[f"/{a}/joint_states" for a in arms]], env=env, capture_output=True, text=True,
                               cwd="/", timeout=args.seconds + 120)
        c1, t1 = cpu_ticks(node.pid), time.monotonic()
    finally:
        node.send_signal(signal.SIGTERM)
        _, err = node.communicate(timeout=30)
    if probe.returncode != 0:
        print(probe.stderr, file=sys.stderr)
        return 1
    got = json.loads(out.read_text())
    for a in arms:
        print(f"  /{a}/joint_states: {figures(got.get(f'/{a}/joint_states', []), cell.heartbeat_hz)}")
    cpu = 100.0 * (c1 - c0) / os.sysconf("SC_CLK_TCK") / (t1 - t0)
    print(f"  droid-ros2 CPU: {cpu:.2f} % of one core over {t1 - t0:.1f} s (with this subscriber; includes discovery)")
    print(f"  droid-ros2 said: {' | '.join(err.strip().splitlines()[-2:])}")
    # the floor: the same subscriber on a plain rclpy publisher at the heartbeat rate
    fl = Path(out.parent) / "floor.json"
    pub = subprocess.Popen([sys.executable, str(PROBE), "floor-pub", "/floor/joint_states", str(args.seconds + 30),
                            str(cell.heartbeat_hz)], env=env, cwd="/", stdout=subprocess.PIPE, text=True)
    try:
        subprocess.run([sys.executable, str(PROBE), "stream", str(fl), str(min(args.seconds, 30.0)),
                        "/floor/joint_states"], env=env, capture_output=True, text=True, cwd="/",
                       timeout=args.seconds + 120, check=True)
    finally:
        pub.send_signal(signal.SIGINT)
        try:
            pub.wait(timeout=30)
        except subprocess.TimeoutExpired:
            pub.kill()
            pub.wait()
    floor = json.loads(fl.read_text()).get("/floor/joint_states", [])
    print(f"  floor, plain rclpy publisher -> the same subscriber: {figures(floor, cell.heartbeat_hz)}")
    print(f"  floor, {cyclictest_floor()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
