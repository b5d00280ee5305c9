#!/usr/bin/env python3
"""Benchmarks of the cell foundation (issue 2): prints figures, decides nothing.

  heartbeat lateness  the heartbeat's own loop (timerfd, absolute deadlines), idle and
                      with one core kept busy by a spinning process
  tick delivery       PUB -> SUB of the tick frame to 4 subscribers (ipc://)
  exchange            the per-tick command/status round trip remote <-> agent
                      (DEALER/ROUTER, a 176-byte command, a 216-byte status, ipc:// and tcp://)
  locked access       Database.read() / update() of a 216-byte record

Usage: bench/bench_foundation.py [--seconds 60] [--fifo]
Record the printed figures with the machine and date in docs/benchmarks.md.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import platform
import statistics
import sys
import tempfile
import threading
import time
import uuid

import numpy as np
import zmq

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from droid.brain.plumbing import wire  # noqa: E402
from droid.brain.runtime.heartbeat import HeartbeatCore  # noqa: E402
from droid.brain.db.layouts import ARM_COMMAND_LAYOUT, ARM_STATUS_LAYOUT, new_record  # noqa: E402
from droid.brain.runtime.rt import PeriodicTimer, try_sched_fifo  # noqa: E402
from droid.brain.db.shmdb import Database, db_name  # noqa: E402
from droid.cli import ArgumentParser, duration_s  # noqa: E402


def pct(values, q):
    return float(np.percentile(np.asarray(values), q))


def line(label, values_us):
    print(f"  {label:<34} median {statistics.median(values_us):8.1f} us   p99 {pct(values_us, 99):8.1f} us"
          f"   max {max(values_us):8.1f} us   (n={len(values_us)})")


def spin(stop):
    while not stop.is_set():
        pass


def heartbeat_lateness(seconds, fifo, busy):
    ctx = mp.get_context("fork")
    stop = ctx.Event()
    burner = ctx.Process(target=spin, args=(stop,)) if busy else None
    if burner:
        burner.start()
    try:
        pid = os.fork()
        if pid == 0:  # measure in a fresh process so SCHED_FIFO does not stick to us
            try_sched_fifo(wanted=fifo, prog="bench")
            period = int(1e9 / 60)
            core = HeartbeatCore(period)
            late = []
            with PeriodicTimer(period) as t:
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    n = t.wait()
                    core.step(n, time.monotonic_ns())
                    late.append(t.lateness_ns / 1e3)
                over = t.overruns
            line(f"heartbeat lateness ({'busy core' if busy else 'idle'}{', FIFO' if fifo else ''})", late)
            print(f"  {'':<34} missed ticks {over} of {len(late) + over}")
            os._exit(0)
        os.waitpid(pid, 0)
    finally:
        if burner:
            stop.set()
            burner.join()


def tick_delivery(seconds, ipc_dir):
    ctx = zmq.Context()
    ep = f"ipc://{ipc_dir}/hb"
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    results = []

    def sub_thread(n):
        s = ctx.socket(zmq.SUB)
        s.setsockopt(zmq.SUBSCRIBE, b"")
        s.connect(ep)
        lat = []
        while True:
            f = s.recv()
            if f == b"END":
                break
            lat.append((time.monotonic_ns() - wire.unpack_tick(f).t_ns) / 1e3)
        results.append(lat)
        s.close()

    subs = [threading.Thread(target=sub_thread, args=(i,)) for i in range(4)]
    for s in subs:
        s.start()
    time.sleep(0.3)
    core = HeartbeatCore(int(1e9 / 60))
    with PeriodicTimer(int(1e9 / 60)) as t:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            n = t.wait()
            pub.send(wire.pack_tick(core.step(n, time.monotonic_ns())))
    pub.send(b"END")
    for s in subs:
        s.join()
    pub.close()
    ctx.term()
    line("tick delivery to 4 SUB (threads)", [v for r in results for v in r])


def _agent(ep, stop):
    ctx = zmq.Context()
    r = ctx.socket(zmq.ROUTER)
    r.bind(ep)
    status = new_record(ARM_STATUS_LAYOUT).tobytes()
    while not stop.is_set():
        if r.poll(100):
            frames = r.recv_multipart()
            tick, _ = wire.unpack_link(frames[1:], wire.KIND_CMD)
            r.send_multipart([frames[0]] + wire.pack_link(wire.KIND_STA, tick, status))
    r.close(0)
    ctx.term()


def exchange(n, ep):
    ctxp = mp.get_context("fork")
    stop = ctxp.Event()
    p = ctxp.Process(target=_agent, args=(ep, stop))
    p.start()
    ctx = zmq.Context()
    d = ctx.socket(zmq.DEALER)
    d.connect(ep)
    cmd = new_record(ARM_COMMAND_LAYOUT).tobytes()
    time.sleep(0.3)
    rtt = []
    for i in range(n):
        t0 = time.perf_counter_ns()
        d.send_multipart(wire.pack_link(wire.KIND_CMD, i, cmd))
        frames = d.recv_multipart()
        wire.unpack_link(frames, wire.KIND_STA)
        rtt.append((time.perf_counter_ns() - t0) / 1e3)
        time.sleep(1 / 600)
    d.close(0)
    ctx.term()
    stop.set()
    p.join()
    line(f"exchange round trip {ep.split(':')[0]}://", rtt)


def locked_access(n):
    name = db_name("bench" + uuid.uuid4().hex[:6], "arm1", "status")
    db = Database(name, ARM_STATUS_LAYOUT, create=True)
    try:
        for label, fn in (("locked read (216 B copy)", db.read), ("locked update (2 fields)",
                                                                   lambda: db.update(busy=1, homed=1))):
            v = []
            for _ in range(n):
                t0 = time.perf_counter_ns()
                fn()
                v.append((time.perf_counter_ns() - t0) / 1e3)
            line(label, v)
    finally:
        db.unlink()


def main():
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=duration_s(), default=60.0, help="duration of each timed run [s]")
    ap.add_argument("--fifo", action="store_true", help="also measure the heartbeat under SCHED_FIFO")
    args = ap.parse_args()
    print(f"# bench_foundation  {time.strftime('%Y-%m-%d %H:%M')}  {platform.node()}  "
          f"{platform.machine()}  {os.cpu_count()} CPUs  Python {platform.python_version()}")
    heartbeat_lateness(args.seconds, False, False)
    heartbeat_lateness(args.seconds, False, True)
    if args.fifo:
        heartbeat_lateness(args.seconds, True, False)
        heartbeat_lateness(args.seconds, True, True)
    with tempfile.TemporaryDirectory() as d:
        tick_delivery(min(args.seconds, 20), d)
        exchange(3000, f"ipc://{d}/agent")
    exchange(3000, "tcp://127.0.0.1:47311")
    locked_access(20000)


if __name__ == "__main__":
    main()
