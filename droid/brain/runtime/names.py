"""droid-names: the cell's name space (thesis §3.2).

"In order for a subunit to be connected to the database it must identify itself
using a unique identifier or name which is placed in the system's name space."
Agents (and the heartbeat) *register* a name -> ZeroMQ endpoint; remotes and
tasks *locate* a name; ``droid-names --list`` prints the table.

Entries are leases: a registrant renews its entry (``keepalive``) at least
every ``ttl_s / 3`` and an entry not renewed for ``ttl_s`` disappears.  An
entry whose registrant runs on this host (same Linux boot id) and whose pid is
dead disappears at once.

Protocol (ROUTER <- DEALER, one JSON object per frame, answers carry the id):
``{"op": "register", "id": n, "name": s, "endpoint": s, "pid": n, "host": s, "ttl_s": x}``,
``{"op": "unregister", ...}``, ``{"op": "locate", "name": s}``, ``{"op": "list"}``.
Replies: ``{"id": n, "ok": true, ...}`` or ``{"id": n, "ok": false, "error": s}``.
"""
from __future__ import annotations

import json
import os
import sys
import time

import zmq

from droid.brain.plumbing.curve import CurveHost
from droid.brain.runtime.program import Presence, Stop, notify_ready, open_cell, parser, presence_key
from droid.brain.db.shmdb import pid_alive
from droid.cli import RuntimeFailure, run

PROG = "droid-names"
DEFAULT_TTL_S = 3.0
MAX_FRAME = 4096
_NAME_MAX = 64
PID_MAX = 1 << 22  # Linux's highest pid_max


def boot_id() -> str:
    """This host's identity for pid checks (Linux boot id)."""
    try:
        with open("/proc/sys/kernel/random/boot_id") as f:
            return f.read().strip()
    except OSError:
        return "unknown"


class NameSpaceCore:
    """The name table.  Pure: time is passed in [ns]; pid checks are injected."""

    def __init__(self, host: str, alive=pid_alive) -> None:
        self.host = host
        self.alive = alive
        self.entries: dict[str, dict] = {}

    def expire(self, now_ns: int) -> None:
        for name in list(self.entries):
            e = self.entries[name]
            if now_ns >= e["expires_ns"] or (e["host"] == self.host and not self.alive(e["pid"])):
                del self.entries[name]

    def handle(self, req: dict, now_ns: int) -> dict:
        self.expire(now_ns)
        op = req.get("op")
        rid = req.get("id")
        out = {"id": rid}
        name = req.get("name")
        if op in ("register", "unregister", "locate"):
            if not isinstance(name, str) or not 0 < len(name) <= _NAME_MAX:
                return {**out, "ok": False, "error": "name must be a string of 1-64 characters"}
        if op == "register":
            ep, pid, host = req.get("endpoint"), req.get("pid"), req.get("host")
            ttl = req.get("ttl_s", DEFAULT_TTL_S)
            if not isinstance(ep, str) or not ep.startswith(("ipc://", "tcp://", "inproc://")):
                return {**out, "ok": False, "error": "endpoint must be an ipc://, tcp:// or inproc:// string"}
            if not isinstance(pid, int) or isinstance(pid, bool) or not 0 < pid <= PID_MAX \
                    or not isinstance(host, str):
                return {**out, "ok": False, "error": f"pid must be an integer 1..{PID_MAX} and host a string"}
            if not isinstance(ttl, (int, float)) or not 0.1 <= ttl <= 3600:
                return {**out, "ok": False, "error": "ttl_s must be between 0.1 and 3600"}
            cur = self.entries.get(name)
            if cur and (cur["pid"], cur["host"]) != (pid, host):
                return {**out, "ok": False,
                        "error": f"name {name!r} is registered by pid {cur['pid']} on another process"}
            self.entries[name] = {"name": name, "endpoint": ep, "pid": pid, "host": host,
                                  "ttl_s": float(ttl), "expires_ns": now_ns + int(ttl * 1e9),
                                  "since_ns": cur["since_ns"] if cur else now_ns}
            return {**out, "ok": True}
        if op == "unregister":
            cur = self.entries.get(name)
            if cur and cur["pid"] == req.get("pid"):
                del self.entries[name]
            return {**out, "ok": True}
        if op == "locate":
            cur = self.entries.get(name)
            if not cur:
                return {**out, "ok": False, "error": f"name {name!r} is not registered"}
            return {**out, "ok": True, "endpoint": cur["endpoint"], "pid": cur["pid"]}
        if op == "list":
            rows = [{k: e[k] for k in ("name", "endpoint", "pid", "host")} |
                    {"age_s": round((now_ns - e["since_ns"]) / 1e9, 3)}
                    for e in sorted(self.entries.values(), key=lambda e: e["name"])]
            return {**out, "ok": True, "entries": rows}
        return {**out, "ok": False, "error": f"unknown op {op!r}"}


class NameClient:
    """Client of the name space over a DEALER socket (never blocks the caller for long)."""

    def __init__(self, ctx: zmq.Context, endpoint: str, *, ttl_s: float = DEFAULT_TTL_S,
                 timeout_s: float = 0.5, curve: CurveHost | None = None, server_host: str = "") -> None:
        """``curve``: this host's CURVE keys; ``server_host``: the name space's host (the Brain)."""
        self.ctx, self.endpoint, self.ttl_s, self.timeout_s = ctx, endpoint, ttl_s, timeout_s
        self.curve, self.server_host = curve, server_host
        self._id = 0
        self._mine: dict[str, str] = {}
        self._last_keepalive = 0.0
        self._open()

    def _open(self) -> None:
        self.sock = self.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SNDHWM, 16)
        if self.curve is not None:
            self.curve.client(self.sock, self.endpoint, self.server_host)
        self.sock.connect(self.endpoint)

    def _send(self, req: dict) -> int:
        self._id += 1
        req["id"] = self._id
        try:
            self.sock.send(json.dumps(req).encode(), zmq.NOBLOCK)
        except zmq.Again:
            pass
        return self._id

    def _request(self, req: dict, timeout_s: float | None = None) -> dict | None:
        rid = self._send(req)
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not self.sock.poll(max(1, int(left * 1000))):
                # Lazy Pirate: a lost request leaves nothing behind on a DEALER,
                # but reopen so a restarted server is reached afresh.
                self.sock.close(0)
                self._open()
                return None
            try:
                rep = json.loads(self.sock.recv())
            except (ValueError, RecursionError, zmq.ZMQError):
                continue
            if isinstance(rep, dict) and rep.get("id") == rid:
                return rep

    def register(self, name: str, endpoint: str, *, wait: bool = True) -> bool:
        """Register ``name`` -> ``endpoint``; True once the server confirmed it."""
        self._mine[name] = endpoint
        req = {"op": "register", "name": name, "endpoint": endpoint, "pid": os.getpid(),
               "host": boot_id(), "ttl_s": self.ttl_s}
        self._last_keepalive = time.monotonic()
        if not wait:
            self._send(req)
            return False
        rep = self._request(req)
        if rep is not None and not rep.get("ok"):
            raise RuntimeFailure(f"name space refused {name!r}: {rep.get('error')}")
        return rep is not None

    def keepalive(self) -> None:
        """Renew our registrations every ttl/3 (fire and forget; drains replies)."""
        while True:
            try:
                self.sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
        if time.monotonic() - self._last_keepalive < self.ttl_s / 3:
            return
        for name, ep in self._mine.items():
            self.register(name, ep, wait=False)

    def locate(self, name: str, timeout_s: float | None = None) -> str | None:
        """Endpoint registered for ``name``, or None (not registered / server silent)."""
        rep = self._request({"op": "locate", "name": name}, timeout_s)
        if rep and rep.get("ok"):
            return rep["endpoint"]
        return None

    def list(self) -> list[dict] | None:
        rep = self._request({"op": "list"})
        return rep["entries"] if rep and rep.get("ok") else None

    def unregister_all(self) -> None:
        for name in list(self._mine):
            self._send({"op": "unregister", "name": name, "pid": os.getpid()})
        self._mine.clear()

    def close(self) -> None:
        self.unregister_all()
        self.sock.close(linger=100)


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Run the cell's name space, or query it (--list, --locate NAME).")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--list", action="store_true", help="print the registered names and exit")
    g.add_argument("--locate", metavar="NAME", help="print NAME's endpoint and exit")
    ap.add_argument("--json", action="store_true", help="with --list: one JSON object a line")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    if args.list or args.locate:
        return _query(cell, args)
    Stop.install()
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, cell.brain_host)
    sock = ctx.socket(zmq.ROUTER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.MAXMSGSIZE, MAX_FRAME)
    presence = Presence(cell.name, presence_key(PROG), PROG)
    core = NameSpaceCore(boot_id())
    try:
        cell.run_dir.mkdir(parents=True, exist_ok=True)
        curve.bind(cell, (sock, cell.names))
        presence.ready()
        notify_ready(args.ready_fd)
        cycles = 0
        bad_frames = 0
        while not Stop.requested:
            if sock.poll(200):
                frames = sock.recv_multipart()
                cycles += 1
                if len(frames) != 2:
                    bad_frames += 1
                    continue
                ident, body = frames
                try:
                    req = json.loads(body)
                    if not isinstance(req, dict):
                        raise ValueError
                except (ValueError, RecursionError):
                    bad_frames += 1
                    sock.send_multipart([ident, json.dumps({"ok": False, "error": "not a JSON object"}).encode()])
                    continue
                rep = core.handle(req, time.monotonic_ns())
                sock.send_multipart([ident, json.dumps(rep).encode()])
            else:
                core.expire(time.monotonic_ns())
            presence.beat(cycles=cycles, bad_frames=bad_frames)
    finally:
        sock.close(0)
        curve.close()
        ctx.term()
        presence.close()
    return 0


def _query(cell, args) -> int:
    ctx = zmq.Context()
    try:
        client = NameClient(ctx, cell.names, timeout_s=1.0, curve=CurveHost(ctx, cell, cell.brain_host),
                            server_host=cell.brain_host)
        try:
            if args.locate:
                ep = client.locate(args.locate)
                if ep is None:
                    raise RuntimeFailure(f"{args.locate!r} not found in the name space of cell {cell.name!r}")
                print(ep)
                return 0
            rows = client.list()
            if rows is None:
                raise RuntimeFailure(f"name space of cell {cell.name!r} does not answer (is the cell up?)")
            for r in rows:
                print(json.dumps(r) if args.json else f"{r['name']:<16} {r['endpoint']:<40} pid {r['pid']}")
            return 0
        finally:
            client.sock.close(0)
    finally:
        ctx.term()


if __name__ == "__main__":
    sys.exit(main())
