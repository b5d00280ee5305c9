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
* ``pull`` (servo commands): PULL in front, PUSH behind, faulted.

The proxy answers JSON requests on a REP control socket
``ipc://<run_dir>/fault.<label>.ctl``: ``{"set": {"drop": 0.2, ...}}``,
``{"get": true}``; each answer carries the current faults and the counts.
"""
from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass

import zmq

from droid.brain.cellfile import Cell
from droid.cli import BadInput
from droid.faults.core import DelayLine, LinkFaults, MessageFate

KINDS = ("router", "pub", "pull")
POLL_MS = 20  # the longest the loop waits with messages held back (delay resolution ~1 ms)


@dataclass(frozen=True)
class Endpoint:
    label: str  # "brain.heartbeat", "arm1.agent", ...
    public: str  # the endpoint in the cell file (connectors use it)
    kind: str  # router, pub or pull
    host: str  # the host whose program binds it


def cell_endpoints(cell: Cell) -> dict[str, Endpoint]:
    """Every endpoint of the cell that a program binds, by label."""
    out = [Endpoint("brain.names", cell.names, "router", cell.brain_host),
           Endpoint("brain.heartbeat", cell.heartbeat, "pub", cell.brain_host)]
    for sub in cell.subunits.values():
        if not any(p.endswith("agent") and p != "droid-servo-agent" for p in sub.programs):
            continue  # a serial sensor: no agent
        out.append(Endpoint(f"{sub.name}.agent", sub.agent, "router", sub.host))
        out.append(Endpoint(f"{sub.name}.relay", sub.relay, "pub", sub.host))
        if "droid-servo" in sub.programs:
            for key, kind in (("servo", "pull"), ("servo_status", "pub")):
                ep = sub.options.get(key)
                if isinstance(ep, str):
                    out.append(Endpoint(f"{sub.name}.{key}", ep, kind, sub.host))
    return {e.label: e for e in out}


def endpoint(cell: Cell, label: str) -> Endpoint:
    eps = cell_endpoints(cell)
    if label not in eps:
        raise BadInput(f"unknown endpoint {label!r} (cell {cell.name}: {', '.join(eps)})")
    return eps[label]


def inner_endpoint(public: str) -> str:
    """The default inner endpoint for a public one: ``ipc://X`` -> ``ipc://X.inner``,
    ``tcp://H:P`` -> ``tcp://H:P+1000``."""
    if public.startswith("tcp://"):
        host, _, port = public[6:].rpartition(":")
        return f"tcp://{host}:{int(port) + 1000}"
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
        self.control = control_endpoint(cell, label)
        self.faults = faults or LinkFaults()
        self.up = MessageFate(seed)  # towards the owner
        self.down = MessageFate(seed + 1)  # from the owner
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

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
    def serve(self, stop=None) -> None:
        stop = stop or (lambda: False)
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
            front.bind(self.ep.public)
            ctl.bind(self.control)
            if back is not None:
                back.connect(self.inner)
                if kind == "pub":
                    poller.register(back, zmq.POLLIN)
            poller.register(front, zmq.POLLIN)
            poller.register(ctl, zmq.POLLIN)
            self._ready.set()
            while not self._stop.is_set() and not stop():
                now = time.monotonic_ns()
                nxt = min((t for t in (held_up.next_ns(), held_down.next_ns()) if t is not None), default=None)
                wait = POLL_MS if nxt is None else max(0, min(POLL_MS, (nxt - now) // 1_000_000))
                events = dict(poller.poll(wait))
                now = time.monotonic_ns()
                faults = self.faults
                if ctl in events:
                    ctl.send_string(json.dumps(self._control(ctl.recv())))
                if front in events:
                    while True:
                        try:
                            frames = front.recv_multipart(zmq.NOBLOCK)
                        except zmq.Again:
                            break
                        if kind == "pub":  # a subscription: pass it on untouched
                            back.send_multipart(frames)
                            continue
                        for d in self.up.decide(faults):
                            held_up.put(now + d, frames)
                for s in list(dealers.values()) + ([back] if kind == "pub" else []):
                    if s in events:
                        ident = next((i for i, x in dealers.items() if x is s), None)
                        while True:
                            try:
                                frames = s.recv_multipart(zmq.NOBLOCK)
                            except zmq.Again:
                                break
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


def _send(s: zmq.Socket, frames) -> None:
    try:
        s.send_multipart(frames, zmq.NOBLOCK)
    except zmq.Again:
        pass  # the peer is gone or slow: a real link would lose it too


def control(cell: Cell, label: str, request: dict, timeout_s: float = 2.0) -> dict:
    """Send one control request to a running proxy; its JSON answer."""
    from droid.cli import RuntimeFailure

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
