"""A live cell under hostile input (issue 8): random ZeroMQ frames on every endpoint, the
modes of its shared memory, `droid-cell status --json`, and databases of a foreign layout.

Verdicts are counts and states, never times: the programs' bad-frame counters
(presence records, `bad_frames` in `droid-cell status --json`) must have moved,
and every program must still be live afterwards.
"""
from __future__ import annotations

import json
import os
import random
import signal
import stat
import time

import numpy as np
import pytest
import zmq

from droid.brain.plumbing import wire
from droid.brain.cell.cellfile import load_cell
from droid.brain.runtime.launcher import STATUS_KEYS
from droid.brain.runtime.names import boot_id
from droid.brain.db.shmdb import cell_objects
from droid.subunits.reis.endpoints import reis_endpoints
from tests.brain.cellutil import cell_status, droid, make_cell_file, wait_for

pytestmark = pytest.mark.integration
FRAMES_PER_ENDPOINT = 300


def random_message(rng: random.Random) -> list[bytes]:
    """1-5 frames of 0-200 random bytes; a quarter start like a link message."""
    frames = [rng.randbytes(rng.randrange(201)) for _ in range(rng.randint(1, 5))]
    if rng.random() < 0.25:
        frames = [wire.LINK_PROTO, rng.choice([wire.KIND_CMD, wire.KIND_STA, b"XXX"]),
                  rng.randbytes(rng.choice([0, 7, 8, 9])), rng.randbytes(rng.randrange(400))]
    return frames


def rows_by_name(path) -> dict[str, dict]:
    return {r["name"]: r for r in cell_status(path)}


def all_live(path):
    out = droid("droid.brain.runtime.launcher", "status", "--json", "--cell", str(path))
    rows = [json.loads(line) for line in out.stdout.splitlines() if line.strip()]
    return rows if out.returncode == 0 and rows and all(r["live"] for r in rows) else None


def test_status_json_keys_and_shm_modes(sim_cell):
    path = sim_cell
    cell = load_cell(path)
    rows = wait_for(lambda: all_live(path), what="every program live")
    for r in rows:
        assert list(r) == list(STATUS_KEYS), r  # every key, in the documented order
        assert isinstance(r["name"], str) and r["name"].startswith("droid-")
        assert isinstance(r["pid"], int) and r["pid"] > 0
        assert r["alive"] is True and r["live"] is True and r["state"] == "ready"
        assert isinstance(r["last_tick"], int) and isinstance(r["age_s"], float)
        assert all(isinstance(r[k], int) for k in ("cycles", "overruns", "bad_frames"))
    by = {r["name"]: r for r in rows}
    assert by["droid-remote arm1"]["last_tick"] > 0  # tick-driven programs report their tick
    # every shared-memory object and semaphore of the cell is private to its owner (0600)
    entries = cell_objects(cell.name)
    assert any(e.startswith("sem.") for e in entries) and any(not e.startswith("sem.") for e in entries)
    assert {e.split(".")[2] for e in entries if not e.startswith("sem.")} >= {"arm1", "gmf1", "mvs", "proc"}
    for e in entries:
        mode = stat.S_IMODE(os.stat(f"/dev/shm/{e}").st_mode)
        assert mode == 0o600, f"/dev/shm/{e} has mode {mode:04o}"


def test_random_frames_on_every_endpoint_crash_nothing(sim_cell):
    path = sim_cell
    cell = load_cell(path)
    arm1 = cell.subunit("arm1")
    ep = reis_endpoints(cell, arm1)
    wait_for(lambda: all_live(path), what="every program live")
    before = rows_by_name(path)
    rng = random.Random(8)
    ctx = zmq.Context()
    try:
        targets = [  # (socket type that talks to the endpoint, endpoint)
            (zmq.DEALER, arm1.agent),                   # droid-reis-agent ROUTER
            (zmq.DEALER, cell.subunit("gmf1").agent),   # droid-gmf1-agent ROUTER
            (zmq.DEALER, cell.names),                   # droid-names ROUTER
            (zmq.XSUB, cell.heartbeat),                 # droid-heartbeat PUB (upstream frames)
            (zmq.XSUB, arm1.relay),                     # the agent's relay PUB
            (zmq.XSUB, ep.servo_status),                # droid-servo status PUB
            (zmq.PUSH, ep.servo),                       # droid-servo command PULL
        ]
        socks = []
        for kind, endpoint in targets:
            s = ctx.socket(kind)
            s.setsockopt(zmq.LINGER, 0)
            s.setsockopt(zmq.SNDTIMEO, 2000)
            s.connect(endpoint)
            socks.append(s)
        for s in socks:
            for _ in range(FRAMES_PER_ENDPOINT):
                msg = random_message(rng)
                if s.type == zmq.PUSH:
                    msg = [msg[0]]  # the servo reads single frames
                s.send_multipart(msg)
        # JSON objects the name space must refuse; a pid of 10**30 used to kill it
        names = socks[2]
        for req in ({"op": "register", "name": "evil", "endpoint": "ipc:///x", "pid": 10 ** 30,
                     "host": boot_id()}, {"op": "locate"}, [1, 2], {"op": "list", "id": {"a": [1]}}):
            names.send(json.dumps(req).encode())
        names.send(b"[" * 2000)

        def counters_moved():
            rows = rows_by_name(path)
            moved = {n: rows[n]["bad_frames"] > before[n]["bad_frames"]
                     for n in ("droid-reis-agent arm1", "droid-gmf1-agent gmf1", "droid-names",
                               "droid-servo arm1")}
            return all(moved.values()) and rows
        wait_for(counters_moved, what="bad-frame counters of the agents, names and servo moved")
        # the name space still answers; every program is still live; the arm's link works
        out = droid("droid.brain.runtime.names", "--list", "--json", "--cell", str(path))
        listed = {json.loads(line)["name"] for line in out.stdout.splitlines()}
        assert out.returncode == 0 and {"heartbeat", "arm1", "gmf1"} <= listed and "evil" not in listed
        rows = wait_for(lambda: all_live(path), what="every program still live")
        assert {r["pid"] for r in rows} == {r["pid"] for r in before.values()}  # nobody restarted

        # -- the SUB side: the remotes' heartbeat subscription gets random frames from an
        # impostor heartbeat (the real one is stopped and its endpoint taken over)
        hb_pid = before["droid-heartbeat"]["pid"]
        os.kill(hb_pid, signal.SIGTERM)
        wait_for(lambda: not _alive(hb_pid), what="the heartbeat to stop")
        pub = ctx.socket(zmq.PUB)
        pub.setsockopt(zmq.LINGER, 0)
        pub.bind(cell.heartbeat)
        remote = "droid-remote arm1"
        start = rows_by_name(path)[remote]["bad_frames"]

        def remote_counted_garbage():
            for _ in range(20):
                pub.send(rng.randbytes(rng.choice([0, 1, 39, 40, 41, 100])))
            pub.send(wire.pack_tick(wire.Tick(10 ** 6, time.monotonic_ns(), cell.period_ns)))
            r = rows_by_name(path)[remote]
            return r["bad_frames"] > start and r
        wait_for(remote_counted_garbage, what="droid-remote to count the impostor's frames")
        for name, r in rows_by_name(path).items():
            if name != "droid-heartbeat":
                assert r["alive"], f"{name} died"
        pub.close(0)
    finally:
        ctx.destroy(linger=0)


def _alive(pid: int) -> bool:
    from droid.brain.db.shmdb import pid_alive

    return pid_alive(pid)


# ------------------------------------------------------------------ foreign databases

@pytest.mark.parametrize("field,value,reason", [
    ("magic", 0x12345678, "bad magic"),
    ("kind", 5, "holds a ctrl_command record"),
    ("version", 9, "layout version 9"),
    ("size", 123, "record size 123"),
])
def test_foreign_database_refused_by_a_program(tmp_path, cell_name, capsys, field, value, reason):
    """`droid-snoop` on a Status database of a foreign layout: one line, exit 2."""
    from droid.brain.db import layouts as L
    from droid.tasks.snoop import main as snoop

    path = make_cell_file(tmp_path, cell_name)
    out = droid("droid.brain.runtime.launcher", "init", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    try:
        shm = f"/dev/shm/droid.{cell_name}.arm1.status"
        with open(shm, "r+b") as f:
            hdr = np.frombuffer(bytearray(f.read(L.HEADER_SIZE)), dtype=L.HEADER, count=1).copy()
            hdr[0][field] = value
            f.seek(0)
            f.write(hdr.tobytes())
        capsys.readouterr()
        code = snoop(["arm1", "--count", "1", "--cell", str(path)])
        err = capsys.readouterr().err
        assert code == 2, err
        assert reason in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    finally:
        droid("droid.brain.runtime.launcher", "down", "--cell", str(path))
    assert cell_objects(cell_name) == []
