"""CURVE on tcp:// links (docs/design.md §4; thesis §7.1): droid-keys, the [curve] table, and real
sockets on 127.0.0.1 where only the cell's keys get through.

A client with the wrong key is judged by what ZeroMQ reports, not by a wait: its
socket monitor reports a failed handshake (a deterministic event), and only
then is it checked that nothing reached it, or came from it, while a client
with the right key exchanged messages over the same server.
"""
from __future__ import annotations

import os
import stat

import pytest
import zmq
from zmq.utils.monitor import recv_monitor_message

from droid.brain.cell.cellfile import load_cell
from droid.brain.plumbing.curve import CurveHost, load_key_pair, secured
from droid.brain.runtime.keys import main as keys_main
from droid.cli import BadInput
from tests.brain.cellutil import small_tcp_cell

HANDSHAKE_EVENTS = {
    zmq.EVENT_HANDSHAKE_SUCCEEDED: "ok",
    zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL: "failed",
    zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL: "failed",
    zmq.EVENT_HANDSHAKE_FAILED_AUTH: "failed",
}


@pytest.fixture
def keydir(tmp_path):
    """Key pairs of the small cell's hosts (brain, a1) and of a stranger."""
    d = tmp_path / "keys"
    assert keys_main([str(d), "--name", "brain", "--name", "a1", "--name", "stranger"]) == 0
    return d


@pytest.fixture
def cell(tmp_path, cell_name, keydir):
    return load_cell(small_tcp_cell(tmp_path, cell_name, keydir))


@pytest.fixture
def ctx():
    c = zmq.Context()
    yield c
    c.destroy(linger=0)


def stranger_client(sock, cell, server_key_of: str = "brain", own: str = "stranger"):
    """A client with a key pair from the same directory that the cell does not list."""
    pub, sec = load_key_pair(cell.curve.secret_path(own))
    sock.curve_publickey, sock.curve_secretkey = pub, sec
    sock.curve_serverkey = load_key_pair(cell.curve.secret_path(server_key_of))[0]


# ------------------------------------------------------------------ droid-keys


def test_droid_keys_writes_pairs_secret_0600(tmp_path, capsys):
    d = tmp_path / "k"
    assert keys_main([str(d), "--name", "brain", "--name", "arm1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in lines] == ["brain", "arm1"]
    assert stat.S_IMODE(os.stat(d).st_mode) == 0o700
    for n in ("brain", "arm1"):
        assert stat.S_IMODE(os.stat(d / f"{n}.key_secret").st_mode) == 0o600
        assert stat.S_IMODE(os.stat(d / f"{n}.key").st_mode) == 0o644
        public, secret = zmq.auth.load_certificate(d / f"{n}.key_secret")
        assert len(public) == 40 and len(secret) == 40
        assert zmq.auth.load_certificate(d / f"{n}.key") == (public, None)
    first = zmq.auth.load_certificate(d / "brain.key")[0]
    # kept unless --force
    assert keys_main([str(d), "--name", "brain"]) == 0
    assert zmq.auth.load_certificate(d / "brain.key")[0] == first
    assert keys_main([str(d), "--name", "brain", "--force"]) == 0
    assert zmq.auth.load_certificate(d / "brain.key")[0] != first


def test_droid_keys_default_names_are_the_cell_hosts(tmp_path, cell_name):
    d = tmp_path / "k"
    path = small_tcp_cell(tmp_path, cell_name, d, extra="")
    text = path.read_text().replace("[curve]\n", '[curve]\nhosts = { a1 = "arm-one" }\n')
    path.write_text(text)
    assert keys_main([str(d), "--cell", str(path)]) == 0
    assert sorted(os.listdir(d)) == ["arm-one.key", "arm-one.key_secret", "brain.key", "brain.key_secret"]


@pytest.mark.parametrize("args,msg", [
    (["--name", "a.b"], "invalid key name"),
    (["--name", "x", "--name", "x"], "given twice"),
    (["--name", ""], "invalid key name"),
    ([], "required"),
])
def test_droid_keys_bad_input(tmp_path, capsys, args, msg):
    argv = [str(tmp_path / "k"), *args] if args else []
    try:
        code = keys_main(argv)
    except SystemExit as exc:  # argparse's error() exits
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert msg in err and len(err.strip().splitlines()) == 1


def test_droid_keys_dir_is_a_file(tmp_path, capsys):
    f = tmp_path / "f"
    f.write_text("")
    assert keys_main([str(f), "--name", "x"]) == 2
    assert "not a directory" in capsys.readouterr().err


# ------------------------------------------------------------------ the [curve] table


def test_cell_without_curve_uses_no_keys(tmp_path, cell_name, ctx):
    cell = load_cell(small_tcp_cell(tmp_path, cell_name))
    assert cell.curve is None
    s = ctx.socket(zmq.PUB)
    assert CurveHost(ctx, cell, "brain").server(s, cell.heartbeat) is False
    assert s.curve_server == 0
    s.close(0)


def test_curve_table_parsed(cell, keydir):
    c = cell.curve
    assert c.keys == keydir
    assert c.key_name("a1") == "a1" and c.key_name("brain") == "brain"
    assert c.allowed_names() == ["a1", "brain"]
    assert secured("tcp://127.0.0.1:5") and not secured("ipc:///tmp/x") and not secured("inproc://x")


@pytest.mark.parametrize("table,msg", [
    ('[curve]\nbogus = 1\nkeys = "k"\n', "unknown key"),
    ("[curve]\nhosts = {}\n", "needs 'keys'"),
    ('[curve]\nkeys = "k"\nhosts = { mars = "m" }\n', "unknown host"),
    ('[curve]\nkeys = "k"\nhosts = { a1 = "a.1" }\n', "invalid key name"),
    ('[curve]\nkeys = "k"\nallow = "op"\n', "allow must be a list"),
    ('[curve]\nkeys = "k"\nallow = ["../op"]\n', "invalid key name"),
])
def test_bad_curve_tables(tmp_path, cell_name, table, msg):
    path = small_tcp_cell(tmp_path, cell_name, extra="\n" + table)
    with pytest.raises(BadInput, match=msg):
        load_cell(path)


def test_missing_or_exposed_secret_key_refused(cell, ctx, keydir):
    s = ctx.socket(zmq.ROUTER)
    try:
        os.chmod(keydir / "brain.key_secret", 0o644)
        with pytest.raises(BadInput, match="accessible by others"):
            CurveHost(ctx, cell, "brain").server(s, cell.names)
        os.unlink(keydir / "brain.key_secret")
        with pytest.raises(BadInput, match="cannot read"):
            CurveHost(ctx, cell, "brain").server(s, cell.names)
        os.unlink(keydir / "a1.key")
        with pytest.raises(BadInput, match="a1.key: cannot read"):
            CurveHost(ctx, cell, "a1").client(s, cell.names, "a1")
    finally:
        s.close(0)


def test_ipc_endpoints_never_use_curve(cell, ctx):
    curve = CurveHost(ctx, cell, "brain")
    s = ctx.socket(zmq.PUB)
    try:
        assert curve.server(s, "ipc:///tmp/never-bound") is False
        assert curve.client(s, "ipc:///tmp/never-bound", "brain") is False
        assert s.curve_server == 0
    finally:
        s.close(0)
        curve.close()


# ------------------------------------------------------------------ real sockets


def _curve_server(ctx, cell, host: str, kind: int):
    """``host``'s CurveHost and a ``kind`` socket it serves on a loopback TCP port: (host, socket, endpoint)."""
    server = CurveHost(ctx, cell, host)
    sock = ctx.socket(kind)
    sock.setsockopt(zmq.LINGER, 0)
    assert server.server(sock, "tcp://127.0.0.1:*")
    sock.bind("tcp://127.0.0.1:*")
    return server, sock, sock.last_endpoint.decode()


def test_pub_sub_only_the_cell_keys_receive(cell, ctx):
    """A heartbeat-like PUB: the a1 host's SUB receives; no key, a stranger's key, or a
    wrong idea of the server's key receive nothing."""
    server, pub, ep = _curve_server(ctx, cell, "brain", zmq.PUB)
    socks = {k: ctx.socket(zmq.SUB) for k in ("right", "no key", "stranger", "wrong server key")}
    try:
        for s in socks.values():
            s.setsockopt(zmq.LINGER, 0)
            s.subscribe(b"")
        assert CurveHost(ctx, cell, "a1").client(socks["right"], ep, "brain")
        stranger_client(socks["stranger"], cell)
        stranger_client(socks["wrong server key"], cell, server_key_of="a1", own="a1")
        verdicts = {}
        mons = {k: s.get_monitor_socket() for k, s in socks.items()}
        for s in socks.values():
            s.connect(ep)
        for k, m in mons.items():
            verdicts[k] = _first_handshake(m)
            socks[k].disable_monitor()
            m.close(0)
        assert verdicts == {"right": "ok", "no key": "failed", "stranger": "failed",
                            "wrong server key": "failed"}
        got = 0
        for i in range(10000):  # publish until the right subscriber has 5 (a count, not a time)
            pub.send(b"tick %d" % i)
            if socks["right"].poll(2):
                while socks["right"].poll(0):
                    socks["right"].recv()
                    got += 1
            if got >= 5:
                break
        assert got >= 5
        for k in ("no key", "stranger", "wrong server key"):
            assert socks[k].poll(0) == 0, k
    finally:
        for s in socks.values():
            s.close(0)
        pub.close(0)
        server.close()


def _first_handshake(mon, timeout_ms: int = 10000) -> str:
    """The first handshake event on a monitor socket, within ``timeout_ms`` in all (other
    events -- connect retries -- keep coming: a per-event timeout alone could wait forever)."""
    import time

    deadline = time.monotonic() + timeout_ms / 1000
    while (left := deadline - time.monotonic()) > 0 and mon.poll(max(1, int(left * 1000))):
        ev = recv_monitor_message(mon)["event"]
        if ev in HANDSHAKE_EVENTS:
            return HANDSHAKE_EVENTS[ev]
    raise AssertionError("no handshake event within the wait")


def test_router_dealer_wrong_key_neither_heard_nor_answered(cell, ctx):
    """An agent-like ROUTER: the Brain's DEALER is answered; a stranger's requests never
    reach the server (its handshake failed, so ZeroMQ delivers nothing of it)."""
    server, router, ep = _curve_server(ctx, cell, "a1", zmq.ROUTER)
    good, bad = ctx.socket(zmq.DEALER), ctx.socket(zmq.DEALER)
    try:
        for s in (good, bad):
            s.setsockopt(zmq.LINGER, 0)
        assert CurveHost(ctx, cell, "brain").client(good, ep, "a1")
        stranger_client(bad, cell, server_key_of="a1")
        mon = bad.get_monitor_socket()
        bad.connect(ep)
        for i in range(5):
            bad.send_multipart([b"CMD", b"from a stranger %d" % i])
        assert _first_handshake(mon) == "failed"
        bad.disable_monitor()
        mon.close(0)
        good.connect(ep)
        good.send_multipart([b"CMD", b"from the brain"])
        assert router.poll(10000)
        ident, *body = router.recv_multipart()
        assert body == [b"CMD", b"from the brain"]
        router.send_multipart([ident, b"STA"])
        assert good.poll(10000) and good.recv_multipart() == [b"STA"]
        # everything that reached the server came from the right key; the stranger got nothing
        assert router.poll(0) == 0 and bad.poll(0) == 0
    finally:
        good.close(0)
        bad.close(0)
        router.close(0)
        server.close()
