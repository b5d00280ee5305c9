"""Cost of droid-foxglove (issue 29 item 4): CPU [% of one core] and messages per second received.

    PYTHONPATH=. python bench/bench_foxglove.py [--seconds 10] [--rate 30]

Records a short lockstep trial (no cell, no real time), serves it with
``droid-foxglove --file`` as its own process, subscribes one protocol client
(tests/observe/foxglove_client.py) to every channel for ``--seconds``, and
prints the server's CPU time (user + system, /proc/PID/stat) over the wall time
as % of one core, idle (no client) and with the client, and the messages per
second the client decoded per topic.  Prints figures only; the verdict is the
reader's (docs/benchmarks.md).
"""
from __future__ import annotations

import asyncio
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from droid.cli import ArgumentParser, duration_s, rate_hz  # noqa: E402


def proc_cpu_s(pid: int) -> float:
    """User + system CPU time [s] of a running process, from /proc/PID/stat."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def listen(port: int, seconds: float) -> dict[str, int]:
    import aiohttp

    from tests.observe.foxglove_client import OP_MESSAGE_DATA, SUBPROTOCOL, FoxgloveClient

    counts: dict[str, int] = {}
    async with aiohttp.ClientSession() as s:
        async with s.ws_connect(f"ws://127.0.0.1:{port}/", protocols=(SUBPROTOCOL,), max_msg_size=0) as ws:
            c = FoxgloveClient(ws)
            await c.read_handshake(want_channels=10)
            subs = await c.subscribe(list(c.channels))
            by_sub = {s: c.channels[cid] for cid, s in subs.items()}
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                try:
                    msg = await ws.receive(timeout=max(0.01, end - time.monotonic()))
                except asyncio.TimeoutError:
                    break
                if msg.type == aiohttp.WSMsgType.BINARY and msg.data[0] == OP_MESSAGE_DATA:
                    ch = by_sub[struct.unpack_from("<I", msg.data, 1)[0]]
                    c.decode(ch, msg.data[13:])
                    counts[ch["topic"]] = counts.get(ch["topic"], 0) + 1
    return counts


def main(argv=None) -> int:
    ap = ArgumentParser(prog="bench_foxglove.py", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=duration_s(600.0), default=10.0, help="seconds with the client (default 10)")
    ap.add_argument("--rate", type=rate_hz(0.1, 120.0), default=30.0, help="droid-foxglove --rate (default 30)")
    args = ap.parse_args(argv)
    from tests.observe.webutil import lockstep_recording

    with tempfile.TemporaryDirectory() as tmp:
        rec = lockstep_recording(Path(tmp) / "trial.mcap")
        port = free_port()
        proc = subprocess.Popen([sys.executable, "-m", "droid.observe.foxglove", "--file", rec, "--port", str(port),
                                 "--rate", str(args.rate)], cwd=ROOT, stderr=subprocess.DEVNULL)
        try:
            while True:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=1).close()
                    break
                except OSError:
                    time.sleep(0.1)
            time.sleep(1.0)
            c0, t0 = proc_cpu_s(proc.pid), time.monotonic()
            time.sleep(min(args.seconds, 5.0))
            idle = (proc_cpu_s(proc.pid) - c0) / (time.monotonic() - t0) * 100
            c0, t0 = proc_cpu_s(proc.pid), time.monotonic()
            counts = asyncio.run(listen(port, args.seconds))
            wall = time.monotonic() - t0
            busy = (proc_cpu_s(proc.pid) - c0) / wall * 100
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
    print(f"droid-foxglove --rate {args.rate:g}: CPU {idle:.1f} % of one core idle (no client), "
          f"{busy:.1f} % with one client on every channel ({wall:.1f} s); load average {os.getloadavg()[0]:.1f}")
    for topic, n in sorted(counts.items()):
        print(f"  {topic:22s} {n / wall:6.1f} messages/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
