"""droid-web: a live page of the cell, and of recordings (thesis §3.4, §7.3; docs/observe.md).

``droid-web [--cell FILE] [--port 8060] [--bind 127.0.0.1] [--token TOKEN] [--file F.mcap] [--foxglove PORT]``

Serves one page: every subunit's Status (homed, busy, mode, stale, fault,
cmd_result), program health and the heartbeat's lateness, live plots of the
tracking errors and the tool speed, and a 3-D view (three.js, vendored in
``static/vendor/three`` with its licence) of both arms' bodies (capsules along
their links from the forward kinematics, eq. 4.1, sized from the robot files),
the torch and the lead sensor with its laser sheet, the workpiece's surfaces,
the seam map, the tool point and force arrows, with camera presets
(``#view=cell|tool|side``) -- pushed over a WebSocket (``/ws``) at ``--rate``
(30 Hz by default).  With ``--file`` the page opens a recording with a time
slider and a play button (``GET /api/frame?i=N&seam_from=K``).  JSON for scripts: ``GET /api/status`` (one object
per subunit, with its tick) and ``GET /api/cell``.

Read-only: it reads the Brain's databases like a task and has no endpoint
that writes (only GET and the WebSocket, whose incoming messages are ignored
and counted: ``ws_ignored`` in ``/api/cell``).  It binds loopback by default
and refuses a non-loopback ``--bind`` without ``--token`` (then every request
to ``/api/*`` and ``/ws`` needs ``?token=TOKEN`` or ``Authorization: Bearer
TOKEN``; the page and its scripts are served without it and pass on the
page's own ``?token=``).

``--foxglove PORT`` (e.g. 8765) also serves the cell to the Foxglove app on PORT: the
server of ``droid-foxglove`` (:mod:`droid.observe.foxglove`) run beside the page.

Exit: 0 on SIGINT/SIGTERM; 1 cell not up, port in use (named); 2 bad arguments or file.
"""
from __future__ import annotations

import asyncio
import errno
import hmac
import json
import signal
import sys
from pathlib import Path

from aiohttp import WSMsgType, web

from droid.brain.runtime.program import close_all, open_cell, parser
from droid.cli import BadInput, DroidError, RuntimeFailure, is_loopback, rate_hz, run, tcp_port
from droid.observe.sources import FileSource, LiveSource

PROG = "droid-web"
STATIC = Path(__file__).resolve().parent / "static"
DEFAULT_PORT = 8060
DEFAULT_RATE_HZ = 30.0


class WebApp:
    """The aiohttp application: GET routes and one WebSocket; nothing writes."""

    def __init__(self, source, token: str | None, rate_hz: float) -> None:
        self.src = source
        self.token = token
        self.period_s = 1.0 / rate_hz
        self.clients: set[web.WebSocketResponse] = set()
        self.ws_ignored = 0
        self.sent = 0
        self.read_errors = 0
        self.app = web.Application(middlewares=[self._auth])
        self.app.add_routes([web.get("/", self.index), web.get("/api/cell", self.api_cell),
                             web.get("/api/status", self.api_status), web.get("/api/frame", self.api_frame),
                             web.get("/api/seam", self.api_seam), web.get("/api/plots", self.api_plots), web.get("/ws", self.ws),
                             web.static("/static", STATIC, follow_symlinks=False)])
        self.app.on_shutdown.append(self._close_clients)

    @web.middleware
    async def _auth(self, request, handler):
        # the page and its scripts are public code; the data (api/, ws) needs the token
        if self.token is not None and request.path not in ("/", "/favicon.ico") and not request.path.startswith("/static/"):
            got = request.query.get("token") or request.headers.get("Authorization", "").removeprefix("Bearer ")
            if not hmac.compare_digest(got.encode(), self.token.encode()):
                return web.json_response({"error": "token required"}, status=401)
        return await handler(request)

    async def index(self, request):
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def api_cell(self, request):
        m = self.src.meta
        body = {"cell": m.get("cell"), "source": self.src.mode, "recording_source": m.get("source"),
                "heartbeat_hz": m.get("heartbeat_hz"), "subunits": m.get("subunits", []),
                "ws_clients": len(self.clients), "ws_ignored": self.ws_ignored, "ws_sent": self.sent,
                "rate_hz": round(1.0 / self.period_s, 3), "scene": m.get("scene", {})}
        if self.src.mode == "file":
            body["file"] = {"path": self.src.rec.path, "count": len(self.src.snaps),
                            "first_tick": self.src.rec.ticks[0], "last_tick": self.src.rec.ticks[-1]}
        return web.json_response(body)

    async def api_status(self, request):
        return web.json_response(self.src.status())

    async def api_frame(self, request):
        if self.src.mode != "file":
            return web.json_response({"error": "no recording open (droid-web --file F.mcap)"}, status=404)
        try:
            i = int(request.query.get("i", "-1"))
        except ValueError:
            return web.json_response({"error": "i must be an integer"}, status=400)
        try:
            seam_from = max(0, int(request.query.get("seam_from", "0")))
        except ValueError:
            return web.json_response({"error": "seam_from must be an integer"}, status=400)
        if i < 0:
            i = len(self.src.snaps) - 1
        return web.json_response(self.src.frame(i, seam_from))

    async def api_plots(self, request):
        """A recording's plot series, at most ``n`` (default 600) samples evenly over it."""
        if self.src.mode != "file":
            return web.json_response({"error": "no recording open (droid-web --file F.mcap)"}, status=404)
        try:
            n = max(1, min(5000, int(request.query.get("n", "600"))))
        except ValueError:
            return web.json_response({"error": "n must be an integer"}, status=400)
        snaps = self.src.snaps
        step = max(1, len(snaps) // n)
        return web.json_response({"ticks": [s["tick"] for s in snaps[::step]],
                                  "plots": [s["plots"] for s in snaps[::step]]})

    async def api_seam(self, request):
        seam = self.src.seam if self.src.mode == "file" else self.src.view.seam
        return web.json_response({"seam": seam})

    async def ws(self, request):
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=4096)
        await ws.prepare(request)
        self.clients.add(ws)
        try:
            await ws.send_json({"type": "hello", "mode": self.src.mode})
            async for msg in ws:
                if msg.type in (WSMsgType.TEXT, WSMsgType.BINARY):
                    self.ws_ignored += 1  # read-only: nothing a client sends is acted on
                elif msg.type == WSMsgType.ERROR:
                    self.ws_ignored += 1
                    break
        finally:
            self.clients.discard(ws)
        return ws

    async def _close_clients(self, app) -> None:
        for ws in list(self.clients):
            await ws.close()

    async def pump(self) -> None:
        """Live mode: one snapshot to every client each period (absolute deadlines)."""
        loop = asyncio.get_running_loop()
        nxt = loop.time()
        seam_sent = {}
        while True:
            nxt += self.period_s
            if self.clients and self.src.mode == "live":
                try:
                    snap = self.src.snapshot()
                except DroidError as exc:  # a database held too long: skip this period, say so once a second
                    self.read_errors += 1
                    if self.read_errors == 1 or self.read_errors % 30 == 0:
                        print(f"{PROG}: {exc}", file=sys.stderr, flush=True)
                    await asyncio.sleep(self.period_s)
                    continue
                data = json.dumps({"type": "snapshot", **snap})
                n = snap["geo"]["seam_n"]
                for ws in list(self.clients):
                    try:
                        k = seam_sent.get(id(ws), 0)
                        if n > k:
                            await ws.send_str(json.dumps({"type": "seam", "from": k, "points": self.src.view.seam[k:n]}))
                            seam_sent[id(ws)] = n
                        await ws.send_str(data)
                        self.sent += 1
                    except (ConnectionError, RuntimeError):
                        self.clients.discard(ws)
            delay = nxt - loop.time()
            if delay < -1.0:
                nxt = loop.time()
            await asyncio.sleep(max(0.0, delay))


async def serve(app: WebApp, bind: str, port: int, foxglove=None) -> None:
    """Serve until SIGINT/SIGTERM; ``foxglove``: a :class:`droid.observe.foxglove.Service` run beside."""
    runner = web.AppRunner(app.app, access_log=None, handle_signals=False)
    await runner.setup()
    site = web.TCPSite(runner, bind, port, reuse_address=False)
    try:
        await site.start()
    except OSError as exc:
        await runner.cleanup()
        if exc.errno == errno.EADDRINUSE:
            raise RuntimeFailure(f"port {port} on {bind} is in use") from None
        if exc.errno in (errno.EADDRNOTAVAIL, errno.EINVAL):
            raise BadInput(f"--bind {bind}: not an address of this host") from None
        raise RuntimeFailure(f"cannot listen on {bind}:{port}: {exc.strerror}") from None
    print(f"{PROG}: serving {app.src.mode} view of {app.src.meta.get('cell')} on http://{bind}:{port}/",
          file=sys.stderr, flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    pump = asyncio.create_task(app.pump())
    fox = asyncio.create_task(foxglove.run(stop)) if foxglove is not None else None
    waiting = asyncio.create_task(stop.wait())
    try:
        await asyncio.wait([waiting] + ([fox] if fox else []), return_when=asyncio.FIRST_COMPLETED)
    finally:
        stop.set()
        pump.cancel()
        try:
            if fox is not None:
                await fox  # a failure of the Foxglove side (its port in use) ends droid-web with its message
        finally:
            await runner.cleanup()


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Serve a read-only live web page of the cell (or of a recording).")
    ap.add_argument("--port", type=tcp_port, default=DEFAULT_PORT, metavar="PORT",
                    help=f"TCP port (default {DEFAULT_PORT})")
    ap.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                    help="address to listen on (default 127.0.0.1; any other needs --token)")
    ap.add_argument("--token", default=None, metavar="TOKEN", help="require ?token=TOKEN on every request")
    ap.add_argument("--file", default=None, metavar="F.mcap", help="open a recording instead of the live cell")
    ap.add_argument("--rate", type=rate_hz(0.1, 120.0), default=DEFAULT_RATE_HZ, metavar="HZ",
                    help=f"WebSocket snapshots per second (default {DEFAULT_RATE_HZ:g})")
    ap.add_argument("--foxglove", type=tcp_port, default=None, metavar="PORT",
                    help="also serve droid-foxglove's WebSocket on PORT (its default is 8765; same --bind, "
                         "--token, --rate, --file; needs the extra droid[foxglove])")
    args = ap.parse_args(argv)
    if args.token is not None and (len(args.token) < 8 or not args.token.isprintable()):
        ap.error("--token must be at least 8 printable characters")
    if not is_loopback(args.bind) and args.token is None:
        raise BadInput(f"--bind {args.bind} is not loopback: refused without --token TOKEN")
    if args.foxglove is not None:
        from droid.observe import foxglove as fox

        if args.foxglove == args.port:
            raise BadInput(f"--foxglove {args.foxglove}: the page's --port; give the WebSocket another port")
        fox.import_sdk()
    src = FileSource(args.file) if args.file else LiveSource(open_cell(args))
    svc = None
    try:
        if args.foxglove is not None:
            svc = fox.Service(fox.open_source(args.file, args), args.bind, args.foxglove, args.token, args.rate)
        asyncio.run(serve(WebApp(src, args.token, args.rate), args.bind, args.port, svc))
    finally:
        close_all(svc, src)
    return 0


if __name__ == "__main__":
    sys.exit(main())
