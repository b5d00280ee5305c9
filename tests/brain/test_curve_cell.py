"""Integration: a two-host cell over tcp:// on 127.0.0.1 with CURVE keys (thesis §7.1).

The subunit host comes up first, alone: a stranger's command never reaches its
agent, the Brain's key is served.  Then the Brain: the whole chain (name
space, heartbeat, remote <-> agent) runs over CURVE, and a stranger gets no
heartbeat tick and no answer from the name space.
"""
from __future__ import annotations

import pytest
import zmq

from droid.brain.plumbing import wire
from droid.brain.cell.cellfile import load_cell
from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import open_local
from droid.brain.db.layouts import ARM_COMMAND_LAYOUT, CTRL_STATUS_LAYOUT, check_header, new_record
from droid.brain.runtime.names import NameClient
from droid.brain.db.shmdb import cell_objects
from droid.brain.runtime.keys import main as keys_main
from tests.brain.cellutil import cell_status, droid, small_tcp_cell, wait_for
from tests.brain.test_curve import _first_handshake, stranger_client
from tests.brain.test_cell import snoop_json

pytestmark = pytest.mark.integration
CELL = "droid.brain.runtime.launcher"


def command_record(cmd_id: int) -> bytes:
    rec = new_record(ARM_COMMAND_LAYOUT)
    rec["cmd_id"] = cmd_id
    return rec.tobytes()


def presence_of(path, name):
    return next(r for r in cell_status(path) if r["name"] == name)


def test_cell_with_keys_only_its_hosts_get_through(tmp_path, cell_name):
    keys = tmp_path / "keys"
    assert keys_main([str(keys), "--name", "brain", "--name", "a1", "--name", "stranger"]) == 0
    path = small_tcp_cell(tmp_path, cell_name, keys)
    cell = load_cell(path)
    sub = cell.subunit("a1")
    ctx = zmq.Context()
    brain = CurveHost(ctx, cell, "brain")  # this test speaks as the Brain host...
    socks = []

    def sock(kind):
        s = ctx.socket(kind)
        s.setsockopt(zmq.LINGER, 0)
        socks.append(s)
        return s

    def refused(kind, endpoint, server_host, *send):
        """Two clients without the cell's keys (a stranger's pair; no CURVE at all) connect
        and send; both handshakes fail.  Returns the sockets, to check they got nothing."""
        out = []
        for stranger in (True, False):
            s = sock(kind)
            if kind == zmq.SUB:
                s.subscribe(b"")
            if stranger:
                stranger_client(s, cell, server_key_of=cell.curve.key_name(server_host))
            mon = s.get_monitor_socket()
            s.connect(endpoint)
            for frames in send:
                # never block: a client without CURVE fails the handshake as a protocol error,
                # its session ends and a DEALER with no peer would wait forever on a blocking
                # send (a loaded host lets the handshake fail before the sends are queued)
                try:
                    s.send_multipart(frames, zmq.NOBLOCK)
                except zmq.Again:
                    pass  # not even queued: nothing of it can reach the server either
            assert _first_handshake(mon) == "failed", (endpoint, stranger)
            s.disable_monitor()
            mon.close(0)
            out.append(s)
        return out

    try:
        out = droid(CELL, "up", "--host", "a1", "--cell", str(path), timeout=90)
        assert out.returncode == 0, out.stderr
        # -- strangers' commands: the handshakes fail, nothing is answered or copied
        bad = refused(zmq.DEALER, sub.agent, "a1",
                      *(wire.pack_link(wire.KIND_CMD, t, command_record(777)) for t in range(1, 6)))
        # -- the Brain's key: answered with a Status record, the command reaches the controller
        good = sock(zmq.DEALER)
        assert brain.client(good, sub.agent, sub.host)
        good.connect(sub.agent)
        good.send_multipart(wire.pack_link(wire.KIND_CMD, 1, command_record(888)))
        assert good.poll(10000), "the agent did not answer the Brain's key"
        tick, payload = wire.unpack_link(good.recv_multipart(), wire.KIND_STA)
        assert tick == 1
        check_header(payload, CTRL_STATUS_LAYOUT, "reply")
        with open_local(cell, sub, "ctrl_command") as cc:
            assert int(cc.read()["cmd_id"]) == 888
        # exactly one command reached the agent's core: the strangers' ten never did
        row = wait_for(lambda: (lambda r: r if r["cycles"] else None)(presence_of(path, "droid-reis-agent a1")),
                       what="the agent's presence record counts the command")
        assert row["cycles"] == 1 and row["bad_frames"] == 0
        assert [s.poll(0) for s in bad] == [0, 0]

        # -- the Brain comes up: every link of the chain runs over CURVE
        out = droid(CELL, "up", "--host", "brain", "--cell", str(path), timeout=90)
        assert out.returncode == 0, out.stderr
        wait_for(lambda: not snoop_json(path, "a1")[0]["stale"], what="a1 fresh over CURVE")
        assert all(r["live"] for r in wait_for(
            lambda: (lambda rs: rs if all(r["live"] for r in rs) else None)(cell_status(path)),
            what="every program live"))

        # -- heartbeat: the strangers' SUBs fail their handshakes and get no tick
        hb_bad = refused(zmq.SUB, cell.heartbeat, "brain")
        hb_good = sock(zmq.SUB)
        hb_good.subscribe(b"")
        brain.client(hb_good, cell.heartbeat, "brain")
        hb_good.connect(cell.heartbeat)
        ticks = []
        while len(ticks) < 3:
            assert hb_good.poll(10000), "no tick for the Brain's key"
            ticks.append(wire.unpack_tick(hb_good.recv()).tick)
        assert ticks == sorted(ticks)
        assert [s.poll(0) for s in hb_bad] == [0, 0]

        # -- name space: the strangers' locates are never answered; the Brain's is
        nm_bad = refused(zmq.DEALER, cell.names, "brain", [b'{"op": "locate", "name": "a1", "id": 1}'])
        client = NameClient(ctx, cell.names, timeout_s=5.0, curve=brain, server_host="brain")
        try:
            assert client.locate("a1") == sub.agent
        finally:
            client.sock.close(0)
        assert [s.poll(0) for s in nm_bad] == [0, 0]
        # no key at all: droid-names --locate of a cell file without [curve] gets no answer
        plain = path.with_name("plain.toml")
        plain.write_text(path.read_text().split("[curve]")[0])
        out = droid("droid.brain.runtime.names", "--locate", "a1", "--cell", str(plain))
        assert out.returncode == 1 and "not found" in out.stderr
        out = droid("droid.brain.runtime.names", "--locate", "a1", "--cell", str(path))
        assert out.returncode == 0 and out.stdout.strip() == sub.agent
    finally:
        brain.close()
        ctx.destroy(linger=0)  # every socket, monitors included, even after a failed assert
        out = droid(CELL, "down", "--cell", str(path))
        assert out.returncode == 0, out.stderr
        assert cell_objects(cell_name) == []
