"""Wall-clock figures of a link cut in the two-host cell (Brain and arm1 in their own network
namespaces, tcp over a veth pair; tests/faults/test_two_hosts.py checks the behaviour).

    nice -n 5 python bench/fault_two_hosts.py [--reps 5]

Per cut, during a joint move: servo ticks from the cut to zero velocity (the servo's halt
record), and wall-clock ms from the cut to arm1's LINK fault (its agent's detection), to
zero velocity, to the Brain marking arm1 stale; from the restore to the Brain's Status fresh
again and to the end of a 2 s droid-move that succeeds.  Needs root (ip netns).
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import zmq

from droid.brain.cell.cellfile import load_cell
from droid.brain.db.databases import open_brain, open_local
from droid.brain.db.layouts import FAULT_LINK
from droid.cli import ArgumentParser, bounded_int
from droid.faults.cells import CAMPAIGN_STALE_TICKS, TWO_HOST_STALE_TICKS, two_host_cell_text
from droid.faults.netns import HostPair
from droid.subunits.reis.servo_wire import unpack_status


def run(*argv, ns=None, hp=None, timeout=200):
    cmd = [sys.executable, "-m", *argv]
    if ns:
        cmd = hp.exec_argv(ns, cmd)
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(argv)}: {out.stderr.strip()}")
    return out


class Ticks(threading.Thread):
    """(servo tick, receipt time) of every servo status message."""

    def __init__(self, endpoint):
        super().__init__(daemon=True)
        self.ep, self.rows, self.stop = endpoint, [], threading.Event()

    def run(self):
        ctx = zmq.Context()
        s = ctx.socket(zmq.SUB)
        s.setsockopt(zmq.SUBSCRIBE, b"")
        s.connect(self.ep)
        while not self.stop.is_set():
            if s.poll(50):
                self.rows.append((unpack_status(s.recv()).tick, time.monotonic()))
        s.close(0)
        ctx.term()

    def at(self, tick):
        return next((t for k, t in self.rows if k >= tick), None)


def halts(run_dir):
    f = Path(run_dir) / "logs" / "servo-arm1.log"
    return [json.loads(ln.split(": halt ", 1)[1]) for ln in f.read_text().splitlines() if ": halt {" in ln]


def main() -> int:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=bounded_int(1, 1000, "repetitions"), default=5, help="repetitions")
    ap.add_argument("--stale-ticks", type=bounded_int(1, 600, "stale ticks"), default=CAMPAIGN_STALE_TICKS,
                    help="the cell's silence rule [heartbeat ticks] (default %(default)s, the thesis's, which "
                         "docs/safety.md's figures were measured with; the test's cell uses "
                         f"{TWO_HOST_STALE_TICKS})")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="droid-2h-"))
    name = f"b2h{uuid.uuid4().hex[:6]}"
    path = tmp / f"{name}.toml"
    rows = []
    with HostPair(subnet=250) as hp:
        path.write_text(two_host_cell_text(name, str(tmp / "run"), hp.addr_a, hp.addr_b, args.stale_ticks))
        cell = load_cell(path)
        try:
            run("droid.brain.runtime.launcher", "up", "--cell", str(path), "--host", "brain", ns="a", hp=hp)
            run("droid.brain.runtime.launcher", "up", "--cell", str(path), "--host", "arm1", ns="b", hp=hp)
            ctrl = open_local(cell, cell.subunit("arm1"), "ctrl_status")
            brain = open_brain(cell, cell.subunit("arm1"), "status")
            deadline = time.monotonic() + 30
            while int(brain.read()["stale"]) or int(brain.read()["fault"]):
                if time.monotonic() > deadline:
                    raise SystemExit(f"arm1 not fresh and fault-free: fault {int(brain.read()['fault'])}")
                time.sleep(0.1)
            run("droid.tasks.home", "arm1", "--cell", str(path))
            ticks = Ticks(cell.subunit("arm1").options["servo_status"])
            ticks.start()
            targets = [[30000, 0, 0, 0, 0, 60000], [0, 0, 0, 0, 0, 0]]
            for rep in range(args.reps):
                start = np.asarray(ctrl.read()["encoder_pos"]).copy()
                run("droid.tasks.move", "arm1", "joint", *map(str, targets[0]), "8", "--no-wait", "--cell", str(path))
                while np.max(np.abs(np.asarray(ctrl.read()["encoder_pos"]) - start)) < 2000:
                    time.sleep(0.01)
                time.sleep(0.02 * rep)  # a different phase each time
                cut_tick = ticks.rows[-1][0]
                n_halts = len(halts(tmp / "run"))
                t_cut = time.monotonic()
                hp.set_link("b", False)
                t_link = t_stale = None
                while t_link is None or t_stale is None:
                    now = time.monotonic()
                    if t_link is None and int(ctrl.read()["fault"]) & FAULT_LINK:
                        t_link = now
                    if t_stale is None and int(brain.read()["stale"]):
                        t_stale = now
                    time.sleep(0.002)
                while True:
                    h = [r for r in halts(tmp / "run")[n_halts:] if r["standstill_tick"] >= cut_tick]
                    if h:
                        break
                    time.sleep(0.05)
                t_stand = ticks.at(h[0]["standstill_tick"])
                time.sleep(0.5)
                t_restore = time.monotonic()
                hp.set_link("b", True)
                while int(brain.read()["stale"]):
                    time.sleep(0.005)
                t_fresh = time.monotonic()
                ok = subprocess.run([sys.executable, "-m", "droid.tasks.move", "arm1", "joint", *map(str, targets[1]),
                                     "2", "--cell", str(path)], capture_output=True, text=True, timeout=120)
                t_ok = time.monotonic()
                row = {"servo_ticks_cut_to_standstill": h[0]["standstill_tick"] - cut_tick,
                       "ms_cut_to_arm_link_fault": round((t_link - t_cut) * 1e3, 1),
                       "ms_cut_to_standstill": round((t_stand - t_cut) * 1e3, 1) if t_stand else None,
                       "ms_cut_to_brain_stale": round((t_stale - t_cut) * 1e3, 1),
                       "ms_restore_to_brain_fresh": round((t_fresh - t_restore) * 1e3, 1),
                       "s_restore_to_move_done": round(t_ok - t_restore, 2), "move_rc": ok.returncode,
                       "peak_speed_counts_per_tick": h[0]["peak_speed_counts_per_tick"],
                       "starved": h[0]["starved_tick"] >= 0}
                rows.append(row)
                print(json.dumps(row), flush=True)
            ticks.stop.set()
            ctrl.close()
            brain.close()
        finally:
            subprocess.run([sys.executable, "-m", "droid.brain.runtime.launcher", "down", "--cell", str(path)],
                           capture_output=True)
    keys = [k for k in rows[0] if k.startswith(("ms_", "s_", "servo_"))] if rows else []
    summary = {k: {"median": float(np.median([r[k] for r in rows if r[k] is not None])),
                   "max": float(np.max([r[k] for r in rows if r[k] is not None]))} for k in keys}
    print(json.dumps({"reps": len(rows), "machine": f"{platform.node()} {os.cpu_count()} CPUs, "
                      f"Python {platform.python_version()}", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                      "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
