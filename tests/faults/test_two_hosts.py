"""A two-host cell: the Brain in one network namespace, arm1 (and the world) in another,
ZeroMQ over tcp between them on a veth pair (issue 8).

Cut the link during a move: the arm comes to a standstill, measured by the servo
itself in its own ticks (the ``halt`` record on its log, droid.subunits.reis.brake_log,
against the servo tick read just before the cut);
restore it: the arm stays where it stopped until a new command, which then succeeds.
Waits are generous polls; no wall-clock figure decides the verdict (bench/fault_two_hosts.py
measures the wall-clock side).
"""
from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from droid.faults.cells import two_host_cell_text
from tests.brain.cellutil import ROOT, droid, wait_for

pytestmark = pytest.mark.integration
STOP_LIMIT_MS = 100.0  # link cut to zero velocity, in servo time (2 ms a tick)


def in_ns(hp, side, module, *args, timeout=120):
    return subprocess.run(hp.exec_argv(side, [sys.executable, "-m", module, *args]), capture_output=True,
                          text=True, timeout=timeout, cwd=ROOT)


@pytest.fixture
def two_hosts(tmp_path, cell_name, host_pair):
    hp = host_pair
    path = tmp_path / f"{cell_name}.toml"
    path.write_text(two_host_cell_text(cell_name, str(tmp_path / "run"), hp.addr_a, hp.addr_b))
    try:
        out = in_ns(hp, "a", "droid.brain.runtime.launcher", "up", "--cell", str(path), "--host", "brain")
        assert out.returncode == 0, out.stdout + out.stderr
        out = in_ns(hp, "b", "droid.brain.runtime.launcher", "up", "--cell", str(path), "--host", "arm1")
        assert out.returncode == 0, out.stdout + out.stderr
        yield hp, path
    finally:
        out = droid("droid.brain.runtime.launcher", "down", "--cell", str(path))
        assert out.returncode == 0, out.stderr


def snoop(path):
    out = droid("droid.tasks.snoop", "arm1", "--json", "--count", "1", "--rate", "50", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def local_status(path):
    """arm1's own controller Status (host arm1's database, not the Brain's)."""
    from droid.brain.cell.cellfile import load_cell
    from droid.brain.db.databases import open_local

    cell = load_cell(path)
    db = open_local(cell, cell.subunit("arm1"), "ctrl_status")
    try:
        rec = db.read()
        return np.asarray(rec["encoder_pos"]).copy(), int(rec["fault"])
    finally:
        db.close()


def cut_halt(records):
    """The halt record of the last command among `records` (log order), once it is a halt of a
    commanded motion; None while there is none."""
    if not records:
        return None
    last = max(r["last_command_tick"] for r in records)
    rec = next(r for r in records if r["last_command_tick"] == last)
    return rec if rec["peak_speed_counts_per_tick"] >= 5 else None


def halt_records(path):
    """The servo's halt records (droid.subunits.reis.brake_log) from its log."""
    f = path.parent / "run" / "logs" / "servo-arm1.log"
    return [json.loads(ln.split(": halt ", 1)[1]) for ln in f.read_text().splitlines() if ": halt {" in ln]


class ServoTicks:
    """The servo's own tick, from its status messages (the test reads them on host arm1's
    ipc endpoint, which is a file: reachable from any namespace)."""

    def __init__(self, path):
        import zmq

        from droid.brain.cell.cellfile import load_cell

        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(load_cell(path).subunit("arm1").options["servo_status"])

    def latest(self) -> int:
        import zmq

        from droid.subunits.reis.servo_wire import unpack_status

        tick = None
        deadline = time.monotonic() + 10
        while tick is None or self.sock.poll(0):
            assert time.monotonic() < deadline, "no servo status"
            if self.sock.poll(100):
                tick = unpack_status(self.sock.recv(zmq.NOBLOCK)).tick
        return tick

    def close(self):
        self.sock.close(0)
        self.ctx.term()


def test_link_cut_during_a_move_brakes_the_arm_which_stays_stopped_until_a_new_command(two_hosts):
    from droid.brain.db.layouts import FAULT_LINK

    hp, path = two_hosts
    wait_for(lambda: not snoop(path)["stale"], timeout=30, what="the Brain reaches arm1 over tcp")
    home = droid("droid.tasks.home", "arm1", "--cell", str(path), timeout=200)
    assert home.returncode == 0, home.stderr
    start = np.asarray(snoop(path)["encoder_pos"])
    target = [30000, 0, 0, 0, 0, 60000]
    out = droid("droid.tasks.move", "arm1", "joint", *map(str, target), "8", "--no-wait", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    ticks = ServoTicks(path)
    try:
        wait_for(lambda: np.any(np.abs(local_status(path)[0] - start) > 2000), what="moving")
        before_tick = ticks.latest()  # the cut comes after this servo tick ...
        hp.set_link("b", False)  # arm1's host is cut off
        after_tick = ticks.latest()  # ... and has taken effect by this one
    finally:
        ticks.close()
    try:
        pos, _ = wait_for(lambda: (lambda a, b: (b, a[1]) if np.all(np.abs(b[0] - a[0]) <= 2) else None)(
            local_status(path), (time.sleep(0.2), local_status(path))[1]), what="arm1 at a standstill")
        # arm1 itself knows its Brain is gone, and the Brain knows arm1 is gone: each once the
        # cell's stale_ticks have passed (200 ms), which may be after the arm stood still
        wait_for(lambda: local_status(path)[1] & FAULT_LINK, timeout=10, what="arm1's LINK fault")
        wait_for(lambda: snoop(path)["stale"] == 1, timeout=10, what="the Brain marks arm1 stale")
        stopped = pos[0]
        # the cut's halt record is the one of the last command the servo received: a host stall
        # before the cut can leave an earlier halt record (a command followed it), and the
        # world catching up a stall can leave a later settle blip with the same last command
        rec = wait_for(lambda: cut_halt([r for r in halt_records(path) if r["standstill_tick"] >= before_tick]),
                       timeout=20, what="the servo's halt record")
    finally:
        hp.set_link("b", True)
    # the servo's own record: it was moving, and reached zero velocity within 100 ms of
    # servo time after the cut (the way-point froze and the servo agent steps the speed down
    # 1.5 periods after the last tick, before the link loss is declared: docs/safety.md).  The cut took
    # effect between before_tick and after_tick; the test process may be descheduled in
    # between on a loaded host, so the limit is counted from after_tick.
    assert rec["peak_speed_counts_per_tick"] >= 5, rec
    assert (rec["standstill_tick"] - after_tick) * 2.0 <= STOP_LIMIT_MS, (rec, before_tick, after_tick)
    # link back: the Brain sees arm1 again; the arm stays where it stopped
    wait_for(lambda: not snoop(path)["stale"], timeout=30, what="fresh again")
    time.sleep(1.0)
    now = np.asarray(snoop(path)["encoder_pos"])
    assert np.all(np.abs(now - stopped) <= 5), (now, stopped)
    assert np.any(np.abs(now - np.asarray(target)) > 1000)  # the interrupted move was not resumed
    # nothing moved since: no later halt record of a commanded motion.  Under load the world
    # catches up a stall a few ms per servo tick, so the position loop's pull-back of the last
    # counts of overshoot can show as a blip of 2-3 counts/tick after the arm settled (seen
    # once: peak 3, no new command); a resumed move would carry a newer command and speed.
    later = [r for r in halt_records(path) if r["standstill_tick"] > rec["settled_tick"]]
    assert all(r["last_command_tick"] == rec["last_command_tick"] and r["peak_speed_counts_per_tick"] < 5
               for r in later), (rec, later)
    # a new command moves the arm again.  One retry: on this shared 2-core VM the 60 Hz chain
    # occasionally gaps long enough for the servo to brake, and the planner then fails the
    # move (exit 1, docs/safety.md finding 6); a recovery that is broken fails both times.
    errors = []
    for _ in range(2):
        out = droid("droid.tasks.move", "arm1", "joint", *map(str, target), "6", "--cell", str(path), timeout=60)
        if out.returncode == 0:
            break
        errors.append(out.stderr.strip())
    assert out.returncode == 0, errors
    assert np.all(np.abs(np.asarray(snoop(path)["encoder_pos"]) - target) <= 20)
