"""droid-fault on an ABB arm's EGM link (issue 26 item 5): the ``udp`` kind of FaultProxy.

Plain UDP sockets on 127.0.0.1 and ephemeral ports stand in for the robot controller (``ctrl``,
sending to the public address) and for droid-egm (``inner``, bound at the [interpose] inner
address); no cell is brought up.  Verdicts rest on contents, orderings and the proxy's counts;
the only clock checks are lower bounds (a delayed datagram cannot come early) and deadlines
that end a wait which would otherwise never end.
"""
from __future__ import annotations

import collections
import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.cli import BadInput
from droid.faults import cli
from droid.faults.proxy import FaultProxy, cell_endpoints, control, inner_endpoint
from droid.kinematics import load_robot
from droid.subunits.abb.egm_core import EgmCore
from tests.abb.egm_helpers import robot_bytes

HOST = "127.0.0.1"
DEADLINE_S = 30.0  # ends a wait that would never end; never a verdict
MAX_UDP_PAYLOAD = 65507  # the largest IPv4 UDP datagram (65535 - 8 - 20 bytes of headers)


def cell_text(name: str, run: str, public_port: int, inner_port: int | None) -> str:
    """droid-egm's test cell (tests/abb/test_egm_prog.py) with its EGM link interposed."""
    from tests.abb.test_egm_prog import cell_text as egm_cell_text

    interpose = "" if inner_port is None else \
        f'\n[interpose]\n"udp://{HOST}:{public_port}" = "udp://{HOST}:{inner_port}"\n'
    return egm_cell_text(name, run, f"udp://{HOST}:{public_port}") + interpose


def udp(port: int = 0) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    s.bind((HOST, port))
    return s


def free_port() -> int:
    s = udp()
    port = s.getsockname()[1]
    s.close()
    return port


class Link:
    """A cell file with abb.egm interposed, the controller's socket and droid-egm's (the test's)."""

    def __init__(self, tmp_path, name: str) -> None:
        self.inner = udp()  # bound first: its ephemeral port goes into the cell file
        self.ctrl = udp()
        self.public = (HOST, free_port())
        (tmp_path / "run").mkdir(exist_ok=True)
        self.path = tmp_path / f"{name}.toml"
        self.path.write_text(cell_text(name, str(tmp_path / "run"), self.public[1], self.inner.getsockname()[1]))
        self.cell = load_cell(self.path)

    def close(self) -> None:
        self.inner.close()
        self.ctrl.close()


@pytest.fixture
def link(tmp_path, cell_name):
    ln = Link(tmp_path, cell_name)
    yield ln
    ln.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("fault-proxy")]  # every proxy stopped


def recv_n(sock: socket.socket, n: int) -> list[tuple[bytes, tuple, float]]:
    """``n`` datagrams (bytes, source, monotonic arrival time [s]); fails after DEADLINE_S."""
    out = []
    deadline = time.monotonic() + DEADLINE_S
    while len(out) < n:
        left = deadline - time.monotonic()
        assert left > 0, f"only {len(out)} of {n} datagrams came"
        if select.select([sock], [], [], min(left, 0.1))[0]:
            data, src = sock.recvfrom(65536)
            out.append((data, src, time.monotonic()))
    return out


def waiting(sock: socket.socket) -> list[bytes]:
    """Whatever is queued on ``sock`` now (never waits)."""
    out = []
    while select.select([sock], [], [], 0)[0]:
        out.append(sock.recv(65536))
    return out


def wait_until(pred) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while not pred():
        assert time.monotonic() < deadline, "the proxy never got there"
        time.sleep(0.002)


def test_endpoints_interpose_and_cell_file(link, capsys):
    e = cell_endpoints(link.cell)["abb.egm"]
    assert (e.kind, e.host, e.public) == ("udp", "abb", f"udp://{HOST}:{link.public[1]}")
    assert inner_endpoint("udp://127.9.8.7:6510") == "udp://127.9.8.7:7510"
    with pytest.raises(BadInput, match="65535"):
        inner_endpoint("udp://127.0.0.1:65000")
    assert cli.main(["--cell", str(link.path), "interpose", "abb.egm"]) == 0
    p = link.public[1]
    assert f'"udp://{HOST}:{p}" = "udp://{HOST}:{p + 1000}"' in capsys.readouterr().out
    assert cli.main(["--cell", str(link.path), "list", "--json"]) == 0
    rows = {r["endpoint"]: r for r in map(json.loads, capsys.readouterr().out.splitlines()) if "endpoint" in r}
    assert rows["abb.egm"]["kind"] == "udp" and rows["abb.egm"]["interposed"]
    bad = link.path.read_text().replace(f'= "udp://{HOST}:{link.inner.getsockname()[1]}"', '= "ipc:///tmp/x"')
    link.path.write_text(bad)
    with pytest.raises(BadInput, match="udp:// address only"):
        load_cell(link.path)


def test_clean_proxy_forwards_both_ways_byte_for_byte_to_the_newest_source(link):
    payloads = [b"", b"x", os.urandom(1472), os.urandom(MAX_UDP_PAYLOAD)]
    with FaultProxy(link.cell, "abb.egm", seed=1) as proxy:
        for p in payloads:
            link.ctrl.sendto(p, link.public)
        got = recv_n(link.inner, len(payloads))
        assert [d for d, _, _ in got] == payloads
        proxy_src = got[0][1]
        assert {s for _, s, _ in got} == {proxy_src} and proxy_src != link.ctrl.getsockname()
        for d, s, _ in got:
            link.inner.sendto(d[::-1], s)
        back = recv_n(link.ctrl, len(payloads))
        assert [d for d, _, _ in back] == [p[::-1] for p in payloads]
        assert {s for _, s, _ in back} == {link.public}

        ctrl2 = udp()  # the controller restarted EGM from another port
        try:
            ctrl2.sendto(b"second", link.public)
            [(d, s, _)] = recv_n(link.inner, 1)
            assert (d, s) == (b"second", proxy_src)
            link.inner.sendto(b"reply", s)
            assert [(d, s) for d, s, _ in recv_n(ctrl2, 1)] == [(b"reply", link.public)]
            assert proxy.controller == ctrl2.getsockname()
            assert waiting(link.ctrl) == []  # the reply went to the newest source only
        finally:
            ctrl2.close()
        assert proxy.counts()["up"]["passed"] == 5 and proxy.counts()["down"]["passed"] == 5


def test_drop_and_cut_are_silence_both_ways(link):
    with FaultProxy(link.cell, "abb.egm", seed=2) as proxy:
        link.ctrl.sendto(b"hello", link.public)
        [(_, proxy_src, _)] = recv_n(link.inner, 1)
        for i, how in enumerate((["--drop", "1"], ["--cut"])):
            assert cli.main(["--cell", str(link.path), "set", "abb.egm", "--clear", *how]) == 0
            for k in range(10):
                link.ctrl.sendto(b"up %d" % k, link.public)
                link.inner.sendto(b"down %d" % k, proxy_src)
            wait_until(lambda: proxy.up.dropped == 10 * (i + 1) and proxy.down.dropped == 10 * (i + 1))
            assert waiting(link.inner) == [] and waiting(link.ctrl) == []
        assert cli.main(["--cell", str(link.path), "set", "abb.egm", "--clear"]) == 0
        link.ctrl.sendto(b"again", link.public)
        assert recv_n(link.inner, 1)[0][0] == b"again"


def test_duplicate_one_doubles_every_datagram_both_ways(link):
    with FaultProxy(link.cell, "abb.egm", seed=3) as proxy:
        assert control(link.cell, "abb.egm", {"set": {"duplicate": 1.0}})["faults"]["duplicate"] == 1.0
        sent = [b"d%d" % k for k in range(10)]
        for d in sent:
            link.ctrl.sendto(d, link.public)
        got = recv_n(link.inner, 20)
        assert collections.Counter(d for d, _, _ in got) == {d: 2 for d in sent}
        src = got[0][1]
        for d in sent:
            link.inner.sendto(d.upper(), src)
        back = recv_n(link.ctrl, 20)
        assert collections.Counter(d for d, _, _ in back) == {d.upper(): 2 for d in sent}
        c = proxy.counts()
        assert c["up"]["duplicated"] == 10 and c["down"]["duplicated"] == 10


def test_delay_holds_datagrams_back_and_a_later_one_overtakes(link):
    with FaultProxy(link.cell, "abb.egm", seed=4) as proxy:
        proxy.set(delay_ms=300)
        sent = {}
        for k in range(5):
            sent[b"a%d" % k] = time.monotonic()
            link.ctrl.sendto(b"a%d" % k, link.public)
        got = recv_n(link.inner, 5)
        assert [d for d, _, _ in got] == list(sent)  # a constant delay keeps the order
        assert all(t - sent[d] >= 0.3 for d, _, t in got)  # never early (a lower bound)
        assert proxy.counts()["up"]["delayed"] == 5

        proxy.set(delay_ms=2000)  # long, so that the datagram sent after it overtakes it
        t_slow = time.monotonic()
        link.ctrl.sendto(b"slow", link.public)
        wait_until(lambda: proxy.up.delayed == 6)
        assert cli.main(["--cell", str(link.path), "set", "abb.egm", "--clear"]) == 0
        link.ctrl.sendto(b"fast", link.public)
        got = recv_n(link.inner, 2)
        assert [d for d, _, _ in got] == [b"fast", b"slow"]
        assert got[1][2] - t_slow >= 2.0


def test_jitter_reorders_and_loses_nothing(link):
    with FaultProxy(link.cell, "abb.egm", seed=5) as proxy:
        proxy.set(jitter_ms=40)
        sent = [b"j%02d" % k for k in range(64)]
        for d in sent:
            link.ctrl.sendto(d, link.public)
        got = [d for d, _, _ in recv_n(link.inner, 64)]
        assert sorted(got) == sent and got != sent
        assert proxy.counts()["up"]["dropped"] == 0


class EgmSide:
    """droid-egm's core behind the proxy, in virtual time (1 ms a datagram), answering at once;
    the controller's replies counted."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.core = EgmCore(load_robot("abb_irb2400"), stale_ticks=12, heartbeat_hz=60.0)
        self.received = self.replies = 0
        self.seq = 0

    def burst(self, n: int) -> None:
        for _ in range(n):
            self.seq += 1
            self.link.ctrl.sendto(robot_bytes(self.seq), self.link.public)

    def pump(self, proxy: FaultProxy) -> None:
        """Until every datagram the proxy took has reached the core, and every reply the
        controller (the proxy decided every datagram sent so far, none is in the air)."""
        up, down = proxy.up, proxy.down
        deadline = time.monotonic() + DEADLINE_S
        while not (up.passed + up.dropped == self.seq and self.received == up.passed + up.duplicated
                   and down.passed + down.dropped == self.core.counters.replies
                   and self.replies == down.passed + down.duplicated):
            assert time.monotonic() < deadline, "datagrams went missing"
            r, _, _ = select.select([self.link.inner, self.link.ctrl], [], [], 0.01)
            if self.link.inner in r:
                data, src = self.link.inner.recvfrom(65536)
                self.received += 1
                reply = self.core.datagram(data, src, self.received * 1_000_000)
                if reply is not None:
                    self.link.inner.sendto(*reply)
            if self.link.ctrl in r:
                self.link.ctrl.recv(65536)
                self.replies += 1


def test_egm_core_behind_the_proxy_counts_duplicates_reordering_and_losses(link):
    """Bursts of 20 sequence numbers (fewer than the core's 32-number window, so nothing is
    *late*), each delivered in full before the next: with duplicates and jitter the core's
    ``duplicated`` is the proxy's, it sees ``reordered`` numbers and nothing stays ``lost``;
    with drops its ``lost`` is the proxy's ``dropped``."""
    side = EgmSide(link)
    with FaultProxy(link.cell, "abb.egm", seed=6) as proxy:
        side.burst(1)  # the stream's first sample, clean: the core's window starts at it
        side.pump(proxy)
        proxy.set(duplicate=0.5, jitter_ms=30)
        for _ in range(10):
            side.burst(20)
            side.pump(proxy)
        c = side.core.counters
        assert c.late == 0 and c.malformed == 0 and c.reconnects == 0
        assert c.duplicated == proxy.up.duplicated > 0
        assert c.reordered > 0 and c.lost == 0
        assert c.accepted + c.reordered == side.seq == 201

        proxy.set(duplicate=0.0, jitter_ms=0.0, drop=0.3)
        for _ in range(5):
            side.burst(20)
            side.pump(proxy)
        proxy.set(drop=0.0)
        side.burst(1)  # delivered: the drops before it are a gap
        side.pump(proxy)
        assert c.lost == proxy.up.dropped > 0
        assert c.late == 0 and c.duplicated == proxy.up.duplicated
        assert c.replies == c.accepted and side.replies == proxy.down.passed + proxy.down.duplicated
        assert np.isfinite(side.core.sample.feedback_deg).all()


def test_bad_input_is_one_line_with_the_exit_codes(link, tmp_path, cell_name, capsys):
    assert cli.main(["--cell", str(link.path), "proxy", "abb.nope"]) == 2
    assert "unknown endpoint" in capsys.readouterr().err
    plain = tmp_path / "plain.toml"
    plain.write_text(cell_text(cell_name + "p", str(tmp_path / "run"), link.public[1], None))
    assert cli.main(["--cell", str(plain), "proxy", "abb.egm"]) == 2
    assert "not interposed" in capsys.readouterr().err
    assert cli.main(["--cell", str(link.path), "set", "abb.egm", "--drop", "0.2"]) == 1  # no proxy runs
    assert "no fault proxy answers" in capsys.readouterr().err

    holder = udp(link.public[1])  # someone else has the public port
    try:
        r = subprocess.run([sys.executable, "-m", "droid.faults.cli", "--cell", str(link.path), "proxy", "abb.egm"],
                           capture_output=True, text=True, timeout=60)
    finally:
        holder.close()
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert "cannot bind UDP" in lines[0] and "in use" in lines[0] and str(link.public[1]) in lines[0]


def test_droid_fault_proxy_and_set_on_the_egm_link(link, capsys):
    """The program itself: ``droid-fault proxy abb.egm`` forwards, ``set --drop 1`` silences it,
    SIGTERM ends it (exit 0) with its counts on stdout."""
    p = subprocess.Popen([sys.executable, "-m", "droid.faults.cli", "--cell", str(link.path), "proxy", "abb.egm",
                          "--seed", "7"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert select.select([p.stderr], [], [], DEADLINE_S)[0], "the proxy said nothing"
        assert "proxy on abb.egm" in p.stderr.readline()
        control(link.cell, "abb.egm", {"get": True}, timeout_s=DEADLINE_S)  # bound and serving
        link.ctrl.sendto(b"one", link.public)
        assert recv_n(link.inner, 1)[0][0] == b"one"
        assert cli.main(["--cell", str(link.path), "set", "abb.egm", "--drop", "1"]) == 0
        assert json.loads(capsys.readouterr().out)["faults"]["drop"] == 1.0
        for _ in range(3):
            link.ctrl.sendto(b"lost", link.public)
        wait_until(lambda: control(link.cell, "abb.egm", {"get": True})["counts"]["up"]["dropped"] == 3)
        assert waiting(link.inner) == []
    finally:
        p.send_signal(signal.SIGTERM)
        try:
            out, err = p.communicate(timeout=DEADLINE_S)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert p.returncode == 0, err
    counts = json.loads(out)
    assert counts["up"] == {"passed": 1, "dropped": 3, "duplicated": 0, "delayed": 0}
