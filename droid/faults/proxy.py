"""A ZeroMQ man-in-the-middle on one endpoint of a cell (the fault injector's link shell).

Every endpoint a program binds can be *interposed*: the cell file's
``[interpose]`` table names an inner endpoint the owner binds instead, and a
:class:`FaultProxy` binds the public one, connects to the inner one and
forwards every message through a :class:`~droid.faults.core.MessageFate`
(drop, delay, duplicate, or cut).  Kinds, by the owner's socket:

* ``router`` (agent link, name space): ROUTER in front, one DEALER per client
  behind, so the agent still sees one peer per remote; both directions faulted;
* ``pub`` (heartbeat, relay, servo status): XPUB in front, XSUB behind;
  subscriptions pass untouched, data is faulted;
* ``pull`` (servo commands): PULL in front, PUSH behind, faulted;
* ``udp`` (an ABB arm's EGM link, the subunit's ``egm`` address): plain UDP, no ZeroMQ.  One
  socket bound at the public address faces the robot controller, one ephemeral socket sends to
  the inner address droid-egm binds; datagrams to droid-egm go through the ``up`` fates, its
  replies through the ``down`` fates to the controller's newest source address.  Datagrams pass
  byte for byte whatever their size (an IPv4 UDP payload is at most 65507 bytes; droid-egm
  drops the oversized ones itself).  droid-egm sees one source, the proxy's socket.

The proxy answers JSON requests on a REP control socket
``ipc://<run_dir>/fault.<label>.ctl``: ``{"set": {"drop": 0.2, ...}}``,
``{"get": true}``; each answer carries the current faults and the counts.
"""
from __future__ import annotations

import json
import socket
import threading
import time
from dataclasses import dataclass

import zmq

from droid.brain.cell.cellfile import Cell
from droid.brain.plumbing.udp import bind_udp, udp_address
from droid.cli import BadInput, RuntimeFailure
from droid.faults.core import DelayLine, LinkFaults, MessageFate

KINDS = ("router", "pub", "pull", "udp")
POLL_MS = 20  # the longest the loop waits with messages held back (delay resolution ~1 ms)
#: a receive buffer larger than any UDP datagram [bytes] (nothing is ever truncated)
UDP_RECV_BYTES = 65536
#: datagrams read from one UDP socket per wake-up, at most (a flood cannot starve the control
#: socket or the held-back datagrams)
UDP_READS_PER_WAKE = 256
#: the UDP sockets' kernel buffers asked for [bytes] (the kernel caps them at its rmem/wmem_max)
UDP_SOCKET_BUFFER_BYTES = 1 << 20


@dataclass(frozen=True)
class Endpoint:
    label: str  # "brain.heartbeat", "arm1.agent", ...
    public: str  # the endpoint in the cell file (connectors use it)
    kind: str  # router, pub, pull or udp
    host: str  # the host whose program binds it


def cell_endpoints(cell: Cell) -> dict[str, Endpoint]:
    """Every endpoint of the cell that a program binds, by label; after a subunit's ZeroMQ ones
    those its device packages declare (``DevicePackage.proxy_endpoints``, every package asked of
    every subunit in the registry's order: an ABB subunit's EGM address ``<sub>.egm``, kind
    ``udp``; a malformed ``egm`` URL is BadInput)."""
    from droid.brain.cell.registry import registry, resolve

    declared = [resolve(p.proxy_endpoints) for p in registry().packages.values() if p.proxy_endpoints]
    out = [Endpoint("brain.names", cell.names, "router", cell.brain_host),
           Endpoint("brain.heartbeat", cell.heartbeat, "pub", cell.brain_host)]
    for sub in cell.subunits.values():
        has_agent = any(p.endswith("agent") and p != "droid-servo-agent" for p in sub.programs)
        if has_agent:  # a serial sensor has none
            out.append(Endpoint(f"{sub.name}.agent", sub.agent, "router", sub.host))
            out.append(Endpoint(f"{sub.name}.relay", sub.relay, "pub", sub.host))
        if has_agent and "droid-servo" in sub.programs:
            for key, kind in (("servo", "pull"), ("servo_status", "pub")):
                ep = sub.options.get(key)
                if isinstance(ep, str):
                    out.append(Endpoint(f"{sub.name}.{key}", ep, kind, sub.host))
        for endpoints in declared:  # checked there: droid-fault list / interpose / proxy refuse a bad one
            out += [Endpoint(f"{sub.name}.{name}", url, kind, sub.host) for name, url, kind in endpoints(cell, sub)]
    return {e.label: e for e in out}


def endpoint(cell: Cell, label: str) -> Endpoint:
    eps = cell_endpoints(cell)
    if label not in eps:
        raise BadInput(f"unknown endpoint {label!r} (cell {cell.name}: {', '.join(eps)})")
    return eps[label]


def inner_endpoint(public: str) -> str:
    """The default inner endpoint for a public one: ``ipc://X`` -> ``ipc://X.inner``,
    ``tcp://H:P`` -> ``tcp://H:P+1000``, ``udp://H:P`` -> ``udp://H:P+1000``."""
    if public.startswith("tcp://"):
        host, _, port = public[6:].rpartition(":")
        return f"tcp://{host}:{int(port) + 1000}"
    if public.startswith("udp://"):
        host, port = udp_address(public)
        if port + 1000 > 65535:
            raise BadInput(f"{public}: no default inner address (port {port} + 1000 > 65535): "
                           f"write the [interpose] entry by hand")
        return f"udp://{host}:{port + 1000}"
    return public + ".inner"


def interpose_table(cell: Cell, labels) -> str:
    """TOML text of an ``[interpose]`` table for these endpoint labels (append to the cell file)."""
    lines = ["[interpose]   # droid-fault proxies serve these endpoints; their owners bind the inner ones"]
    for label in labels:
        e = endpoint(cell, label)
        lines.append(f'"{e.public}" = "{inner_endpoint(e.public)}"')
    return "\n".join(lines) + "\n"


def control_endpoint(cell: Cell, label: str) -> str:
    return f"ipc://{cell.run_dir}/fault.{label}.ctl"


class FaultProxy:
    """Forwards one endpoint's messages through seeded faults.  ``start()`` runs it in a
    thread (tests, the campaign); ``serve()`` runs it in the calling thread (droid-fault)."""

    def __init__(self, cell: Cell, label: str, faults: LinkFaults | None = None, seed: int = 0) -> None:
        self.ep = endpoint(cell, label)
        self.inner = cell.bind_endpoint(self.ep.public)
        if self.inner == self.ep.public:
            raise BadInput(f"endpoint {label} ({self.ep.public}) is not interposed in the cell file: "
                           f"add an [interpose] entry for it (droid-fault interpose {label})")
        if self.ep.kind == "udp":
            for url in (self.ep.public, self.inner):
                udp_address(url)  # malformed: BadInput here, before serving
        self.controller: tuple | None = None  # udp: the newest source address seen at the public one
        self.control = control_endpoint(cell, label)
        self.faults = faults or LinkFaults()
        self.up = MessageFate(seed)  # towards the owner
        self.down = MessageFate(seed + 1)  # from the owner
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._on_ready = None

    # -- lifecycle ---------------------------------------------------------------
    def start(self, timeout_s: float = 5.0) -> "FaultProxy":
        self._thread = threading.Thread(target=self._run_thread, name=f"fault-proxy {self.ep.label}", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError(f"fault proxy {self.ep.label} did not start")
        if self._error is not None:
            raise self._error
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)

    def __enter__(self) -> "FaultProxy":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def set(self, **faults) -> LinkFaults:
        """Change the faults (thread-safe: one attribute store)."""
        self.faults = LinkFaults.from_dict(faults, self.faults)
        return self.faults

    def counts(self) -> dict:
        return {"up": self.up.counts(), "down": self.down.counts()}

    def _run_thread(self) -> None:
        try:
            self.serve()
        except BaseException as exc:  # reported by start()
            self._error = exc
            self._ready.set()

    # -- the loop ------------------------------------------------------------------
    def serve(self, stop=None, on_ready=None) -> None:
        """Forward until ``stop()`` is true or :meth:`stop` is called; ``on_ready()`` once every
        socket is bound.  A public (or control) endpoint that cannot be bound is a
        RuntimeFailure (exit 1) of one line."""
        stop = stop or (lambda: False)
        self._on_ready = on_ready
        if self.ep.kind == "udp":
            self._serve_udp(stop)
        else:
            self._serve_zmq(stop)

    def _serving(self) -> None:
        self._ready.set()
        if self._on_ready is not None:
            self._on_ready()

    def _bind(self, sock, where: str) -> None:
        try:
            sock.bind(where)
        except zmq.ZMQError as exc:
            raise RuntimeFailure(f"fault proxy {self.ep.label}: cannot bind {where}: {exc}") from None

    def _turns(self, poller: zmq.Poller, ctl: zmq.Socket, stop, held_up: DelayLine, held_down: DelayLine):
        """The loop's turns, once the proxy is serving, until it is stopped: ``(events, now [ns],
        faults)`` after each poll (woken in time for the next held message), the control socket's
        request already answered."""
        self._serving()
        while not self._stop.is_set() and not stop():
            events = dict(poller.poll(_wait_ms(held_up, held_down)))
            now = time.monotonic_ns()
            faults = self.faults
            if ctl in events:
                ctl.send_string(json.dumps(self._control(ctl.recv())))
            yield events, now, faults

    def _serve_zmq(self, stop) -> None:
        ctx = zmq.Context()
        socks: list[zmq.Socket] = []

        def sock(kind: int) -> zmq.Socket:
            s = ctx.socket(kind)
            s.setsockopt(zmq.LINGER, 0)
            socks.append(s)
            return s

        kind = self.ep.kind
        front = sock({"router": zmq.ROUTER, "pub": zmq.XPUB, "pull": zmq.PULL}[kind])
        back = None if kind == "router" else sock({"pub": zmq.XSUB, "pull": zmq.PUSH}[kind])
        dealers: dict[bytes, zmq.Socket] = {}
        ctl = sock(zmq.REP)
        held_up, held_down = DelayLine(), DelayLine()
        poller = zmq.Poller()
        try:
            self._bind(front, self.ep.public)
            self._bind(ctl, self.control)
            if back is not None:
                back.connect(self.inner)
                if kind == "pub":
                    poller.register(back, zmq.POLLIN)
            poller.register(front, zmq.POLLIN)
            poller.register(ctl, zmq.POLLIN)
            for events, now, faults in self._turns(poller, ctl, stop, held_up, held_down):
                if front in events:
                    for frames in _waiting(front):
                        if kind == "pub":  # a subscription: pass it on untouched
                            back.send_multipart(frames)
                            continue
                        for d in self.up.decide(faults):
                            held_up.put(now + d, frames)
                for s in list(dealers.values()) + ([back] if kind == "pub" else []):
                    if s in events:
                        ident = next((i for i, x in dealers.items() if x is s), None)
                        for frames in _waiting(s):
                            for d in self.down.decide(faults):
                                held_down.put(now + d, frames if ident is None else [ident, *frames])
                for frames in held_up.due(now):
                    if kind == "router":
                        ident, body = frames[0], frames[1:]
                        if ident not in dealers:
                            dl = sock(zmq.DEALER)
                            dl.setsockopt(zmq.SNDHWM, 16)
                            dl.connect(self.inner)
                            dealers[ident] = dl
                            poller.register(dl, zmq.POLLIN)
                        _send(dealers[ident], body)
                    else:
                        _send(back, frames)
                for frames in held_down.due(now):
                    _send(front, frames)
        finally:
            for s in socks:
                s.close(0)
            ctx.term()

    def _serve_udp(self, stop) -> None:
        """The ``udp`` kind's loop: controller <-> public socket, inner socket <-> droid-egm."""
        public, inner = udp_address(self.ep.public), udp_address(self.inner)
        ctx = zmq.Context()
        ctl = ctx.socket(zmq.REP)
        ctl.setsockopt(zmq.LINGER, 0)
        front = back = None
        held_up, held_down = DelayLine(), DelayLine()
        try:
            who = f"fault proxy {self.ep.label}"
            front = bind_udp(public, who, UDP_SOCKET_BUFFER_BYTES)
            back = bind_udp(None, who, UDP_SOCKET_BUFFER_BYTES)
            back.connect(inner)  # an ephemeral port; only droid-egm's datagrams come back on it
            self._bind(ctl, self.control)
            poller = zmq.Poller()
            for s in (front.fileno(), back.fileno(), ctl):
                poller.register(s, zmq.POLLIN)
            for events, now, faults in self._turns(poller, ctl, stop, held_up, held_down):
                if front.fileno() in events:
                    for data, source in _recv_all(front):
                        self.controller = source  # replies go to the controller's newest address
                        for d in self.up.decide(faults):
                            held_up.put(now + d, data)
                if back.fileno() in events:
                    for data, _ in _recv_all(back):
                        for d in self.down.decide(faults):
                            held_down.put(now + d, data)
                now = time.monotonic_ns()
                for data in held_up.due(now):
                    _send_udp(back, data, None)
                for data in held_down.due(now):
                    if self.controller is not None:
                        _send_udp(front, data, self.controller)
        finally:
            for s in (front, back):
                if s is not None:
                    s.close()
            ctl.close(0)
            ctx.term()

    def _control(self, raw: bytes) -> dict:
        try:
            req = json.loads(raw)
            if not isinstance(req, dict):
                raise ValueError("not an object")
            if "set" in req:
                if not isinstance(req["set"], dict):
                    raise ValueError("'set' must be an object")
                self.set(**req["set"])
            return {"ok": True, "label": self.ep.label, "faults": self.faults.as_dict(), "counts": self.counts()}
        except (ValueError, BadInput, TypeError) as exc:
            return {"ok": False, "error": str(exc)}


def _wait_ms(*lines: DelayLine) -> int:
    """How long the loop may sleep [ms]: until the next held message is due, POLL_MS at most."""
    nxt = min((t for t in (ln.next_ns() for ln in lines) if t is not None), default=None)
    return POLL_MS if nxt is None else max(0, min(POLL_MS, (nxt - time.monotonic_ns()) // 1_000_000))


def _waiting(sock: zmq.Socket):
    """The multipart messages waiting on ``sock``, each taken as it is asked for, never blocking."""
    while True:
        try:
            frames = sock.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return
        yield frames


def _recv_all(sock: socket.socket) -> list[tuple[bytes, tuple]]:
    """The datagrams waiting on ``sock`` (UDP_READS_PER_WAKE at most), never blocking."""
    out = []
    for _ in range(UDP_READS_PER_WAKE):
        try:
            out.append(sock.recvfrom(UDP_RECV_BYTES))
        except (BlockingIOError, InterruptedError):
            break
        except OSError:
            continue  # an ICMP error of an earlier send (droid-egm not running): nobody heard it
    return out


def _send_udp(sock: socket.socket, data: bytes, address: tuple | None) -> None:
    try:
        if address is None:
            sock.send(data)
        else:
            sock.sendto(data, address)
    except OSError:
        pass  # the peer is not there, or the buffer is full: a real link would lose it too


def _send(s: zmq.Socket, frames) -> None:
    try:
        s.send_multipart(frames, zmq.NOBLOCK)
    except zmq.Again:
        pass  # the peer is gone or slow: a real link would lose it too


def control(cell: Cell, label: str, request: dict, timeout_s: float = 2.0) -> dict:
    """Send one control request to a running proxy; its JSON answer."""
    ctx = zmq.Context()
    s = ctx.socket(zmq.REQ)
    s.setsockopt(zmq.LINGER, 0)
    try:
        s.connect(control_endpoint(cell, label))
        s.send_string(json.dumps(request))
        if not s.poll(int(timeout_s * 1000)):
            raise RuntimeFailure(f"no fault proxy answers for {label} at {control_endpoint(cell, label)}")
        return json.loads(s.recv())
    finally:
        s.close(0)
        ctx.term()
