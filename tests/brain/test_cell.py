"""Integration: a real cell of processes on loopback, driven through the CLIs.

Each test brings its own uniquely named cell up and always brings it down; the
autouse leak fixture then proves no process, shm object or semaphore is left.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from droid.brain.db.shmdb import cell_objects
from tests.brain.cellutil import brought_down, ROOT, cell_status, droid, free_port, make_cell_file, wait_for

pytestmark = pytest.mark.integration
CELL = "droid.brain.runtime.launcher"
SNOOP = "droid.tasks.snoop"


@pytest.fixture
def cell(tmp_path, cell_name):
    with brought_down(make_cell_file(tmp_path, cell_name), cell_name) as path:
        yield path


def n_programs(path) -> int:
    from droid.brain.cell.cellfile import load_cell
    from droid.brain.runtime.launcher import cell_programs

    first, rest = cell_programs(load_cell(path))
    return len(first) + len(rest)


def up(path):
    out = droid(CELL, "up", "--cell", str(path), timeout=90)
    assert out.returncode == 0, out.stdout + out.stderr
    return out


def snoop_json(path, sub, count=1, rate=20):
    out = droid(SNOOP, sub, "--json", "--count", str(count), "--rate", str(rate), "--cell", str(path))
    assert out.returncode == 0, out.stderr
    return [json.loads(line) for line in out.stdout.splitlines()]


def test_default_cell_up_snoop_down(cell, cell_name):
    up(cell)
    rows = cell_status(cell)
    names = {r["name"] for r in rows}
    assert {"droid-names", "droid-heartbeat", "droid-sim", "droid-remote arm1", "droid-remote gmf1",
            "droid-remote mvs", "droid-remote tool", "droid-reis-agent arm1", "droid-gmf1-agent gmf1",
            "droid-mvs mvs", "droid-servo arm1", "droid-servo-agent arm1",
            "droid-watchdog arm1", "droid-planner arm1"} <= names
    assert len(rows) == n_programs(cell)
    assert all(r["pid"] > 0 for r in rows)
    wait_for(lambda: all(r["live"] for r in cell_status(cell)), what="every program live")
    for sub in ("arm1", "gmf1", "mvs", "tool"):
        # the remote refreshes each subunit's Status from its agent every tick
        recs = wait_for(lambda: [r for r in snoop_json(cell, sub, 2) if not r["stale"]] or None,
                        what=f"{sub} fresh")
        for key in ("x", "y", "z", "R", "encoder_pos", "encoder_cmd", "busy", "homed", "tick", "stale"):
            assert key in recs[0]
        assert recs[-1]["tick"] > 0
    ticks = [r["tick"] for r in snoop_json(cell, "arm1", 3, rate=10)]
    assert ticks == sorted(ticks) and ticks[-1] > ticks[0]
    assert len(cell_objects(cell_name)) > 0
    plain = droid(SNOOP, "gmf1", "--count", "1", "--cell", str(cell))
    assert plain.returncode == 0 and plain.stdout.startswith("gmf1 tick ")


def test_agent_death_marks_stale_and_link_recovers(cell):
    up(cell)
    wait_for(lambda: not snoop_json(cell, "gmf1")[0]["stale"], what="gmf1 fresh")
    agent = next(r for r in cell_status(cell) if r["name"] == "droid-gmf1-agent gmf1")
    os.kill(agent["pid"], signal.SIGKILL)
    wait_for(lambda: snoop_json(cell, "gmf1")[0]["stale"], what="gmf1 stale after its agent died")
    # the other subunits are unaffected
    assert not snoop_json(cell, "arm1")[0]["stale"]
    # the agent comes back (by hand, as a user would restart it): the remote reconnects
    proc = subprocess.Popen([sys.executable, "-m", "droid.subunits.gmf1.agent", "gmf1", "--cell", str(cell)],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: not snoop_json(cell, "gmf1")[0]["stale"], what="gmf1 fresh again")
    finally:
        proc.terminate()
        proc.wait(10)


def test_heartbeat_death_marks_everything_stale_no_crash(cell):
    up(cell)
    wait_for(lambda: not snoop_json(cell, "arm1")[0]["stale"], what="arm1 fresh")
    hb = next(r for r in cell_status(cell) if r["name"] == "droid-heartbeat")
    os.kill(hb["pid"], signal.SIGSTOP)  # a paused heartbeat: no ticks, no exchange
    try:
        t0 = snoop_json(cell, "arm1")[0]["tick"]
        rows = snoop_json(cell, "arm1", 3, rate=10)
        assert all(r["tick"] == t0 for r in rows)  # nothing refreshed without ticks
        # ... and the Brain says so: every subunit goes stale with the heartbeat fault
        for sub in ("arm1", "gmf1", "mvs", "tool"):
            wait_for(lambda: (lambda r: r["stale"] and "heartbeat" in r["fault"])(snoop_json(cell, sub)[0]),
                     what=f"{sub} stale (heartbeat)")
    finally:
        os.kill(hb["pid"], signal.SIGCONT)
    wait_for(lambda: snoop_json(cell, "arm1")[0]["tick"] > t0, what="ticks again")
    wait_for(lambda: (lambda r: not r["stale"] and "heartbeat" not in r["fault"])(snoop_json(cell, "arm1")[0]),
             what="arm1 fresh again, heartbeat fault cleared")
    assert all(r["alive"] for r in cell_status(cell))


def test_second_up_refused_and_status_json(cell):
    up(cell)
    again = droid(CELL, "up", "--cell", str(cell))
    assert again.returncode == 1
    assert "already up" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    rows = cell_status(cell)
    for r in rows:
        assert set(r) >= {"name", "pid", "alive", "live", "last_tick", "state"}


def test_status_and_snoop_of_a_cell_that_is_not_up(tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name)
    st = droid(CELL, "status", "--cell", str(path))
    assert st.returncode == 1 and "not up" in st.stderr
    sn = droid(SNOOP, "arm1", "--count", "1", "--cell", str(path))
    assert sn.returncode == 1 and "is the cell up" in sn.stderr
    dn = droid(CELL, "down", "--cell", str(path))
    assert dn.returncode == 0


def test_failed_start_leaves_nothing(tmp_path, cell_name):
    # the agent endpoint of arm1 is a tcp port that is already taken: its agent cannot bind
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    port = s.getsockname()[1]
    try:
        path = make_cell_file(tmp_path, cell_name)
        text = path.read_text().replace('agent = "ipc://{run}/arm1.agent"', f'agent = "tcp://127.0.0.1:{port}"')
        path.write_text(text)
        out = droid(CELL, "up", "--cell", str(path), timeout=90)
        assert out.returncode == 1
        assert "arm1" in out.stderr and "before it was ready" in out.stderr
        assert cell_objects(cell_name) == []
    finally:
        s.close()




def test_cell_over_tcp_started_host_by_host(tmp_path, cell_name):
    """Every link over tcp:// on loopback, and each host's programs started by its own
    `droid-cell up --host`: the hardware first, then the subunits, then the Brain (thesis
    §3.2: a subunit should be powered and identified before the Brain's initialization
    software runs)."""
    import re

    path = make_cell_file(tmp_path, cell_name)
    text = re.sub(r'"ipc://\{run\}/[a-z0-9.]+"', lambda m: f'"tcp://127.0.0.1:{free_port()}"',
                  path.read_text())
    assert "ipc://" not in text
    assert '[world]\nenabled = true\nhost = "world"' in text  # the hardware on its own host
    path.write_text(text)
    try:
        for hosts in (["world"], ["arm1", "gmf1"], ["mvs"], ["brain"]):
            args = [a for h in hosts for a in ("--host", h)]
            out = droid(CELL, "up", *args, "--cell", str(path), timeout=90)
            assert out.returncode == 0, out.stderr
        again = droid(CELL, "up", "--host", "mvs", "--cell", str(path))
        assert again.returncode == 1 and "already up" in again.stderr
        rows = cell_status(path)
        assert len(rows) == n_programs(path)
        for sub in ("arm1", "gmf1", "mvs", "tool"):
            wait_for(lambda: not snoop_json(path, sub)[0]["stale"], what=f"{sub} fresh over tcp")
        names = droid("droid.brain.runtime.names", "--list", "--json", "--cell", str(path))
        eps = {json.loads(l)["name"]: json.loads(l)["endpoint"] for l in names.stdout.splitlines()}
        # the sensors have serial links, no agents; the joystick and the F/T sensor have the generic agent
        assert set(eps) == {"heartbeat", "arm1", "gmf1", "joy", "ft"}
        assert all(e.startswith("tcp://127.0.0.1:") for e in eps.values())
    finally:
        out = droid(CELL, "down", "--cell", str(path))
        assert out.returncode == 0, out.stderr
        assert cell_objects(cell_name) == []


def test_start_cell_script_by_hand(tmp_path, cell_name):
    """scripts/start-cell.sh starts the cell program by program; droid-cell sees and stops it."""
    path = make_cell_file(tmp_path, cell_name)
    env = dict(os.environ, DROID_CELL=str(path), LOGS=str(tmp_path / "logs"),
               PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    try:
        out = subprocess.run(["bash", str(ROOT / "scripts" / "start-cell.sh")], env=env, cwd=ROOT,
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        rows = wait_for(lambda: (lambda r: r if len(r) == n_programs(path) and all(x["live"] for x in r)
                                 else None)(cell_status(path)), what="every hand-started program live")
        assert {r["name"] for r in rows} >= {"droid-remote arm1", "droid-heartbeat", "droid-names"}
        wait_for(lambda: not snoop_json(path, "arm1")[0]["stale"], what="arm1 fresh")
    finally:
        out = droid(CELL, "down", "--cell", str(path))
        assert out.returncode == 0, out.stderr
    assert cell_objects(cell_name) == []
