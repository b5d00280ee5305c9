"""The fault injector's core (seeded per-message fates) and its ZeroMQ proxy, without a cell."""
from __future__ import annotations

import json
import time

import pytest
import zmq

from droid.brain.cell.cellfile import load_cell
from droid.cli import BadInput
from droid.faults import cli
from droid.faults.core import DelayLine, LinkFaults, MessageFate
from droid.faults.proxy import FaultProxy, control, interpose_table
from tests.brain.cellutil import make_cell_file


def test_fates_are_seeded_and_follow_the_probabilities():
    f = LinkFaults(drop=0.3, duplicate=0.2, delay_ms=5, jitter_ms=2)
    a = [MessageFate(7).decide(f) for _ in range(1)]
    m1, m2 = MessageFate(7), MessageFate(7)
    s1 = [m1.decide(f) for _ in range(2000)]
    s2 = [m2.decide(f) for _ in range(2000)]
    assert s1 == s2 and s1[0] == a[0]
    assert s1 != [MessageFate(8).decide(f) for _ in range(2000)]
    dropped = sum(1 for x in s1 if not x)
    dup = sum(1 for x in s1 if len(x) == 2)
    assert 500 <= dropped <= 700 and 200 <= dup <= 360
    assert all(5e6 <= d <= 9e6 for x in s1 for d in x)
    assert m1.counts()["dropped"] == dropped
    assert all(MessageFate(1).decide(LinkFaults(cut=True)) == [] for _ in range(10))
    assert MessageFate(1).decide(LinkFaults()) == [0]


def test_bad_fault_values_are_refused():
    for bad in ({"drop": 1.5}, {"duplicate": -0.1}, {"delay_ms": float("nan")}, {"nonsense": 1}):
        with pytest.raises(BadInput):
            LinkFaults.from_dict(bad)


def test_delay_line_releases_in_time_order():
    d = DelayLine()
    for t, x in ((30, "c"), (10, "a"), (20, "b"), (10, "a2")):
        d.put(t, x)
    assert d.due(5) == [] and d.next_ns() == 10
    assert d.due(25) == ["a", "a2", "b"] and d.due(100) == ["c"] and len(d) == 0


@pytest.fixture
def cell(tmp_path, cell_name):
    path = make_cell_file(tmp_path, cell_name)
    c = load_cell(path)
    path.write_text(path.read_text() + interpose_table(c, ["arm1.agent", "brain.heartbeat"]))
    (tmp_path / "run").mkdir()
    return load_cell(path)


def _pair(ctx, cell):
    inner = ctx.socket(zmq.ROUTER)
    inner.setsockopt(zmq.LINGER, 0)
    inner.bind(cell.bind_endpoint(cell.subunit("arm1").agent))
    client = ctx.socket(zmq.DEALER)
    client.setsockopt(zmq.LINGER, 0)
    client.connect(cell.subunit("arm1").agent)
    return inner, client


def _drain(sock, wait_s=0.3):
    out = []
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        if sock.poll(20):
            out.append(sock.recv_multipart())
    return out


def test_router_proxy_passes_drops_and_duplicates_and_obeys_its_control_socket(cell):
    ctx = zmq.Context()
    inner, client = _pair(ctx, cell)
    try:
        with FaultProxy(cell, "arm1.agent", seed=3) as proxy:
            client.send_multipart([b"CMD", b"1"])
            got = _drain(inner, 1.0)
            assert len(got) == 1 and got[0][1:] == [b"CMD", b"1"]
            inner.send_multipart([got[0][0], b"STA", b"1"])  # the reply finds its way back
            assert _drain(client, 1.0) == [[b"STA", b"1"]]

            ans = control(cell, "arm1.agent", {"set": {"duplicate": 1.0}})
            assert ans["ok"] and ans["faults"]["duplicate"] == 1.0
            client.send_multipart([b"CMD", b"2"])
            assert [m[1:] for m in _drain(inner)] == [[b"CMD", b"2"]] * 2

            assert cli.main(["--cell", str(cell.path), "set", "arm1.agent", "--clear", "--cut"]) == 0
            for i in range(5):
                client.send_multipart([b"CMD", b"%d" % i])
            assert _drain(inner) == []
            assert proxy.counts()["up"]["dropped"] == 5

            assert cli.main(["--cell", str(cell.path), "set", "arm1.agent", "--clear", "--delay-ms", "150"]) == 0
            client.send_multipart([b"CMD", b"late"])
            got = _drain(inner, 1.0)
            assert [m[1:] for m in got] == [[b"CMD", b"late"]]
            with pytest.raises(SystemExit) as exc:
                cli.main(["--cell", str(cell.path), "set", "arm1.agent", "--drop", "2"])
            assert exc.value.code == 2
            assert control(cell, "arm1.agent", {"set": {"drop": "x"}})["ok"] is False
    finally:
        inner.close(0)
        client.close(0)
        ctx.term()


def test_pub_proxy_forwards_subscriptions_and_faults_data(cell):
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind(cell.bind_endpoint(cell.heartbeat))
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(cell.heartbeat)
    try:
        with FaultProxy(cell, "brain.heartbeat", seed=1) as proxy:
            got = []
            deadline = time.monotonic() + 10
            while not got and time.monotonic() < deadline:  # until the subscription reached the PUB
                pub.send(b"tick")
                got = _drain(sub, 0.05)
            assert got
            proxy.set(drop=1.0)
            _drain(sub, 0.2)
            for _ in range(10):
                pub.send(b"tick")
            assert _drain(sub, 0.3) == []
    finally:
        pub.close(0)
        sub.close(0)
        ctx.term()


def test_an_endpoint_not_interposed_is_refused(cell):
    with pytest.raises(BadInput, match="not interposed"):
        FaultProxy(cell, "arm1.relay")
    with pytest.raises(BadInput, match="unknown endpoint"):
        FaultProxy(cell, "arm9.agent")


def test_cli_list_and_interpose(cell, capsys):
    assert cli.main(["--cell", str(cell.path), "list", "--json"]) == 0
    rows = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    by = {r["endpoint"]: r for r in rows if "endpoint" in r}
    assert by["arm1.agent"]["interposed"] and not by["arm1.relay"]["interposed"]
    assert cli.main(["--cell", str(cell.path), "interpose", "arm1.relay"]) == 0
    assert "arm1.relay.inner" in capsys.readouterr().out
    assert cli.main(["--cell", str(cell.path), "kill", "droid-servo arm1"]) == 1  # the cell is not up


def test_wedged_databases_finds_a_live_holder_and_not_a_dead_one(tmp_path, cell_name):
    """The campaign's lock check can fail: a holder that is alive (here: stopped) wedges its
    database; once it is dead, the next waiter recovers the lock."""
    import os
    import signal
    import subprocess
    import sys

    from droid.brain.db.databases import create_databases
    from droid.brain.db.shmdb import remove_cell_objects
    from droid.faults.cells import campaign_cell_text
    from droid.faults.procs import wedged_databases

    path = tmp_path / f"{cell_name}.toml"
    path.write_text(campaign_cell_text(cell_name, str(tmp_path / "run")))
    c = load_cell(path)
    for db in create_databases(c):
        db.close()
    code = ("import sys,time\nfrom droid.brain.cell.cellfile import load_cell\n"
            "from droid.brain.db.databases import open_local\n"
            "c = load_cell(sys.argv[1]); db = open_local(c, c.subunit('arm1'), 'ctrl_command')\n"
            "db._acquire(); print('held', flush=True); time.sleep(60)\n")
    p = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "held"
        os.kill(p.pid, signal.SIGSTOP)
        assert wedged_databases(c, timeout_s=0.2) == [f"/droid.{cell_name}.arm1.ctrl_command"]
        p.kill()
        p.wait()
        assert wedged_databases(c, timeout_s=0.2) == []
    finally:
        p.kill()
        p.wait()
        p.stdout.close()
        remove_cell_objects(cell_name)


def test_droid_cell_restart_refuses_when_the_cell_is_not_up(cell):
    from droid.brain.runtime import launcher

    assert launcher.main(["restart", "droid-servo arm1", "--cell", str(cell.path)]) == 1
