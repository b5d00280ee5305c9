"""Benchmark of the Net F/T twin's cost in the world's step (docs/ft.md).

droid-sim steps every device at 1 kHz; the twin's share of that step is what this prints:
microseconds of wall time per 1 ms world step, idle (no client) and streaming 500 RDT records
a second to a client on loopback that drains them (the record's reading, counts, sendto).
Figures depend on the machine's load: report them with the machine and the date.

    PYTHONPATH=. python bench/bench_ft_twin.py [--steps N]
"""
from __future__ import annotations

import platform
import socket
import time

import numpy as np

from droid.cli import ArgumentParser, bounded_int
from droid.kinematics.transforms import pose_to_T
from droid.sim.ft.netft import SENSOR_MODELS, NetFtTwin, NetFtTwinDevice
from droid.subunits.ft.rdt import CMD_START_REALTIME, request


class Arm:
    def wcp_global(self):
        return pose_to_T(800.0, 0.0, 900.0, 0.0, 90.0, 0.0)


def main() -> None:
    ap = ArgumentParser(description="Time the Net F/T twin's world step.")
    ap.add_argument("--steps", type=bounded_int(100, 10**7, "steps"), default=5000)
    args = ap.parse_args()
    dev = NetFtTwinDevice("ft", NetFtTwin(SENSOR_MODELS["gamma"], 1, 500.0), Arm(), np.eye(4),
                          pose_to_T(0, 0, 150, 0, 0, 0), 1.5, (0.0, 0.0, 60.0))
    dev.serve()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        t0 = time.perf_counter()
        for _ in range(args.steps):
            dev.advance(0.001)
        idle = (time.perf_counter() - t0) / args.steps
        client.connect(("127.0.0.1", dev.port))
        client.setblocking(False)
        client.send(request(CMD_START_REALTIME))
        t0 = time.perf_counter()
        for i in range(args.steps):
            dev.advance(0.001)
            if i % 50 == 0:
                try:
                    while True:
                        client.recv(64)
                except BlockingIOError:
                    pass
        streaming = (time.perf_counter() - t0) / args.steps
        print(f"machine: {platform.node()} {platform.processor() or platform.machine()}, python "
              f"{platform.python_version()}")
        print(f"idle:      {idle * 1e6:7.1f} us per 1 ms world step")
        print(f"streaming: {streaming * 1e6:7.1f} us per 1 ms world step (500 records/s, {dev.twin.sent} sent)")
    finally:
        client.close()
        dev.close()


if __name__ == "__main__":
    main()
