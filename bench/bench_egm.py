#!/usr/bin/env python3
"""The EGM link in real time (issue 26): droid-egm's round trip, and EGM silence to standstill.

Prints figures; decides nothing.  Two parts, one live cell at a time:

1. **round trip** (``--samples N``): a cell of the Brain and the ABB subunit only (no world):
   this bench plays the robot controller.  From a thread at SCHED_FIFO 70 (above the cell) it
   sends an ``EgmRobot`` datagram every 4 ms (EGM's 250 Hz) to droid-egm's UDP address and
   waits for the ``EgmSensor`` reply: send -> reply received [us], p50 / p99 / max, and the
   datagrams that got no reply within 20 ms.  The figure is droid-egm's time from the
   datagram's arrival to its reply **plus** two loopback passes and this thread's wake-up: an
   upper bound of the time inside droid-egm (target p99 <= 1 ms).
2. **silence** (``--silence K``): a copy of cells/abb_weld.toml with the EGM link interposed
   (``[interpose]``) and a fault proxy (droid.faults.proxy, docs/safety.md) in this process.
   The ABB is homed, then K times: a joint move of axis 1 by 40 deg in 3 s; 1.5 s into it,
   while the arm moves at its fastest, the proxy cuts the link both ways (the PC side falls
   silent, as a crashed or unplugged PC).  From the world's truth door (the twin's true flange,
   ``droid.sim.truth``, 250 Hz of world time), polled at ~2 kHz from a SCHED_FIFO 70 thread:
   cut -> standstill (the flange within 0.01 mm for 200 ms; target <= 100 ms) and how far the
   flange moved after the cut [mm]; from the Brain's Status: cut -> FAULT_DEVICE (the feedback
   stale, ``stale_ticks``).  Then the link is restored and the bench waits until the arm
   takes a move again.

Then the machine's floor (cyclictest, bench/floor.py) measured in the same run, and the load.

Usage: bench/bench_egm.py [--samples 2500] [--silence 5]
"""
from __future__ import annotations

import os
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.floor import cyclictest_floor, when_and_load  # noqa: E402
from bench.live_cell import droid_module as droid, renamed_cell  # noqa: E402
from bench.truth import standstill  # noqa: E402
from droid.brain.cell.cellfile import load_cell  # noqa: E402
from droid.brain.db.databases import open_brain  # noqa: E402
from droid.brain.db.layouts import FAULT_DEVICE  # noqa: E402
from droid.cli import ArgumentParser, bounded_int  # noqa: E402
from droid.kinematics import load_robot  # noqa: E402

SAMPLER_PRIORITY = 70  # > droid.brain.runtime.rt.CEILING_PRIORITY (61)
PERIOD_NS = 4_000_000  # EGM's 4 ms
REPLY_TIMEOUT_S = 0.020


def fifo(prio: int = SAMPLER_PRIORITY) -> bool:
    try:  # this thread only (pid 0 = the calling thread on Linux)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
        return True
    except (PermissionError, OSError):
        return False


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def robot_datagram(seqno: int, joints) -> bytes:
    from droid.subunits.abb import egm_schema as es

    m = es.EgmRobot()
    m.header.seqno = seqno
    m.header.tm = (seqno * 4) & 0xFFFFFFFF
    m.header.mtype = es.MSGTYPE_DATA
    m.feedBack.joints.joints.extend(joints)
    m.planned.joints.joints.extend(joints)
    m.motorState.state = es.MOTORS_ON
    m.rapidExecState.state = es.RAPID_RUNNING
    m.mciState.state = es.MCI_RUNNING
    m.mciConvergenceMet = True
    return m.SerializeToString()


ROUNDTRIP_CELL = """[cell]
name = "{name}"
run_dir = "{run}"
heartbeat_hz = 60.0
stale_ticks = 12
sched_fifo = true
[brain]
host = "brain"
[world]
enabled = false
[subunits.abb]
class = "arm6r"
robot = "abb_irb2400"
host = "abb"
programs = ["droid-reis-agent", "droid-planner", "droid-egm"]
egm = "udp://127.0.0.1:{port}"
"""


def roundtrip(tmp: Path, samples: int) -> str:
    name, port = "e" + uuid.uuid4().hex[:9], free_udp_port()
    path = tmp / "rt.toml"
    path.write_text(ROUNDTRIP_CELL.format(name=name, run=tmp / "rtrun", port=port))
    up = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=180)
    try:
        if up.returncode != 0:
            return f"round trip: the cell did not come up: {up.stderr.strip()[-300:]}"
        rtt: list[float] = []
        lost = [0]
        got_fifo = [False]

        def loop() -> None:
            got_fifo[0] = fifo()
            joints = [0.0, 10.0, 10.0, 0.0, 60.0, 0.0]
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.bind(("127.0.0.1", 0))
                s.setblocking(False)
                t_next = time.monotonic_ns()
                for k in range(1, samples + 1):
                    while select.select([s], [], [], 0)[0]:  # late replies of earlier samples
                        s.recv(65536)
                    t_next += PERIOD_NS
                    data = robot_datagram(k, joints)
                    t0 = time.monotonic_ns()
                    s.sendto(data, ("127.0.0.1", port))
                    if select.select([s], [], [], REPLY_TIMEOUT_S)[0]:
                        t1 = time.monotonic_ns()
                        s.recv(65536)
                        if k > 25:  # the first ones connect the link (not a steady state)
                            rtt.append((t1 - t0) / 1e3)
                    else:
                        lost[0] += 1
                    time.sleep(max(0.0, (t_next - time.monotonic_ns()) / 1e9))

        th = threading.Thread(target=loop, daemon=True)
        th.start()
        th.join()
        if not rtt:
            return "round trip: no replies"
        a = np.array(rtt)
        return (f"round trip (send EgmRobot -> EgmSensor back, {len(a)} samples at 250 Hz, bench thread "
                f"{'SCHED_FIFO 70' if got_fifo[0] else 'normal'}): p50 {np.percentile(a, 50):.0f} us, "
                f"p99 {np.percentile(a, 99):.0f} us, max {a.max():.0f} us; no reply within 20 ms: {lost[0]}")
    finally:
        droid("droid.brain.runtime.launcher", "down", "--cell", str(path), timeout=120)


class TruthSampler(threading.Thread):
    """Polls the world's truth door for the ABB and the Brain's Status fault bits (~2 kHz)."""

    def __init__(self, cell) -> None:
        super().__init__(daemon=True)
        from droid.sim.truth import TruthDoor, door_name

        self.door = TruthDoor.open(door_name(cell.name, "abb"))
        self.status = open_brain(cell, cell.subunit("abb"), "status")
        self.flange: list[tuple[int, np.ndarray]] = []  # (seen ns, true flange position mm)
        self.device_ns: int | None = None
        self.after_ns = 0
        self.stop = threading.Event()

    def run(self) -> None:
        fifo()
        last_t = None
        while not self.stop.is_set():
            tr = self.door.read(0.0)
            now = time.monotonic_ns()
            if tr is not None and tr[0] != last_t:
                last_t = tr[0]
                self.flange.append((now, np.array(tr[2])))
            if self.device_ns is None and now >= self.after_ns and int(self.status.read()["fault"]) & FAULT_DEVICE:
                self.device_ns = now
            time.sleep(0.0005)

    def close(self) -> None:
        self.stop.set()
        self.join(2.0)
        self.door.close()
        self.status.close()


def silence_run(cell_path: Path, cell, proxy, k: int, counts) -> str:
    """One cut during a fast joint move; the figures of that run as one line."""
    sign = 1 if k % 2 == 0 else -1
    target = counts([sign * 20.0, 10.0, 10.0, 0.0, 60.0, 0.0])
    mv = subprocess.Popen([sys.executable, "-m", "droid.tasks.move", "abb", "--cell", str(cell_path), "joint",
                           "--", *(str(int(c)) for c in target), "3"], cwd=ROOT, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
    s = TruthSampler(cell)
    s.start()
    time.sleep(1.5)  # half-way: the fastest part of the move
    t_cut = time.monotonic_ns()
    s.after_ns = t_cut
    proxy.set(cut=True)
    time.sleep(2.5)
    proxy.set(cut=False)
    _, err = mv.communicate(timeout=60)
    s.close()
    still = standstill(s.flange, t_cut)
    before = [p for t, p in s.flange if t <= t_cut]
    after = [p for t, p in s.flange if t > t_cut]
    moved = max((float(np.linalg.norm(p - before[-1])) for p in after), default=float("nan")) if before else float("nan")
    speed = (float(np.linalg.norm(before[-1] - before[-20]) / ((20 - 1) * 0.004)) if len(before) > 20
             else float("nan"))
    if os.environ.get("BENCH_EGM_TRACE"):  # the flange after the cut: ms, distance to the rest [mm]
        rest = s.flange[-1][1]
        print(" ".join(f"{(t - t_cut) / 1e6:.0f}:{np.linalg.norm(p - rest):.3f}" for t, p in s.flange
                       if t_cut - 20e6 <= t <= t_cut + 300e6), flush=True)
    dev = "never" if s.device_ns is None else f"{(s.device_ns - t_cut) / 1e6:.0f} ms"
    st = "none within the record" if still is None else f"{(still - t_cut) / 1e6:.0f} ms"
    return (f"silence run {k}: flange at {speed:.0f} mm/s when cut; cut -> standstill {st}, moved {moved:.2f} mm "
            f"after the cut; cut -> FAULT_DEVICE in the Brain {dev}; droid-move exit {mv.returncode} "
            f"({err.strip().splitlines()[-1] if err.strip() else ''})")


def silence(tmp: Path, runs: int) -> None:
    from droid.faults.proxy import FaultProxy, inner_endpoint

    name = "s" + uuid.uuid4().hex[:9]
    text = (ROOT / "cells" / "abb_weld.toml").read_text()
    text = renamed_cell(text, name, f"{tmp}/srun")
    cell_path = tmp / "abb.toml"
    cell_path.write_text(text)
    egm = load_cell(str(cell_path)).subunit("abb").options["egm"]
    cell_path.write_text(text + f'\n[interpose]\n"{egm}" = "{inner_endpoint(egm)}"\n')
    cell = load_cell(str(cell_path))
    model = load_robot("abb_irb2400")

    def counts(q):
        return np.rint(model.gearing.joints_to_counts(np.asarray(q, float))).astype(int)

    (tmp / "srun").mkdir()
    proxy = FaultProxy(cell, "abb.egm").start()  # before the cell: the twin's first datagram finds it
    up = droid("droid.brain.runtime.launcher", "up", "--cell", str(cell_path), timeout=180)
    try:
        if up.returncode != 0:
            print("silence: the cell did not come up:", up.stderr.strip()[-300:], flush=True)
            return
        out = droid("droid.tasks.home", "abb", "--cell", str(cell_path), timeout=120)
        if out.returncode != 0:
            print(f"silence: droid-home abb failed: {out.stderr.strip()}", flush=True)
            return
        for k in range(runs):
            print(silence_run(cell_path, cell, proxy, k, counts), flush=True)
            for _ in range(60):  # until the link is back and the arm takes a move again
                back = droid("droid.tasks.move", "abb", "--cell", str(cell_path), "joint", "--",
                             *(str(int(c)) for c in counts([0.0, 10.0, 10.0, 0.0, 60.0, 0.0])), "1", timeout=60)
                if back.returncode == 0:
                    break
                time.sleep(0.5)
            else:
                print(f"silence run {k}: the arm took no move again within 30 s: {back.stderr.strip()}", flush=True)
                return
        print(f"proxy counts: {proxy.counts()}", flush=True)
    finally:
        droid("droid.brain.runtime.launcher", "down", "--cell", str(cell_path), timeout=120)
        proxy.stop()


def main() -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=bounded_int(0, 100000, "samples"), default=2500,
                    help="round-trip datagrams (0: skip)")
    ap.add_argument("--silence", type=bounded_int(0, 50, "runs"), default=5, help="silence runs (0: skip)")
    args = ap.parse_args()
    print(when_and_load(), flush=True)
    with tempfile.TemporaryDirectory(prefix="droid-egm-") as tmpd:
        tmp = Path(tmpd)
        if args.samples:
            print(roundtrip(tmp, args.samples), flush=True)
            print(cyclictest_floor(5.0), flush=True)
        if args.silence:
            silence(tmp, args.silence)
    print(cyclictest_floor(5.0), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
