"""Cost of recording a cell with droid-record (issue 14): CPU [% of one core] and size [MB/min].

    PYTHONPATH=. python bench/bench_record.py [--seconds 60] [--cell FILE] [--offline]

Live (default): brings the built-in simulated cell up (renamed, run dir in a
temporary directory; or uses ``--cell FILE`` if that cell is already up), runs
``droid-record --out ... --seconds S`` on it as its own process at the cell's
60 Hz heartbeat, and reports that process's CPU time (user + system, from
wait4) over the wall time as % of one core (target <= 5 %), the file's size
per minute and the ticks it holds against the ticks elapsed.  Then it runs
droid-web on the cell for 10 s and counts the snapshots a WebSocket client
receives per second (>= 20 wanted), and brings the cell down again.

``--offline``: no processes -- the recording core alone (CellRecorder with the
sampler reading every Brain database, health every 12 ticks) on a cell's
databases without programs, per tick [us] and as % of one core at 60 Hz; and
one droid-web live snapshot (databases read, link frames, JSON) [us].
Prints figures only; the verdict is the reader's (docs/benchmarks.md).
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from droid.brain.cell.cellfile import builtin_cell_path, load_cell  # noqa: E402
from droid.cli import ArgumentParser, duration_s  # noqa: E402


def temp_cell(tmp: Path, name: str) -> Path:
    text = builtin_cell_path().read_text().replace('name = "sim"', f'name = "{name}"\nrun_dir = "{tmp}/run"', 1)
    path = tmp / "cell.toml"
    path.write_text(text)
    return path


def droid(module: str, *args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=timeout,
                          env=env, cwd=ROOT)


def proc_cpu_s(pid: int) -> float:
    """User + system CPU time [s] of a running process, from /proc/PID/stat."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def live(args, tmp: Path) -> None:
    own = args.cell is None
    cell_file = temp_cell(tmp, f"benchrec{os.getpid()}") if own else Path(args.cell)
    if own:
        out = droid("droid.brain.runtime.launcher", "up", "--cell", str(cell_file))
        if out.returncode != 0:
            sys.exit(f"bench_record: cell did not come up: {out.stderr.strip()}")
    try:
        hz = load_cell(cell_file).heartbeat_hz
        path = tmp / "bench.mcap"
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "droid.observe.record", "--cell", str(cell_file),
                                 "--out", str(path), "--seconds", str(args.seconds)],
                                env=env, cwd=ROOT, stderr=subprocess.PIPE, text=True)
        # steady state: CPU between 3 s after the start (imports done) and 1 s before the end
        time.sleep(3.0)
        cpu_a, wall_a = proc_cpu_s(proc.pid), time.monotonic()
        time.sleep(max(0.5, args.seconds - 4.0))
        cpu_b, wall_b = proc_cpu_s(proc.pid), time.monotonic()
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.monotonic() - t0
        err = proc.stderr.read().strip()
        proc.stderr.close()
        if os.waitstatus_to_exitcode(status) != 0:
            sys.exit(f"bench_record: droid-record failed: {err}")
        cpu = ru.ru_utime + ru.ru_stime
        from droid.observe.mcapfile import read_recording

        rec = read_recording(path)
        size = os.path.getsize(path)
        span = rec.ticks[-1] - rec.ticks[0] + 1
        print(f"cell {load_cell(cell_file).name}, {hz:g} Hz heartbeat, {args.seconds:g} s recorded "
              f"(wall {wall:.1f} s incl. start-up)")
        print(f"droid-record CPU: {cpu:.2f} s user+system = {100 * cpu / wall:.2f} % of one core "
              f"with start-up; steady state {100 * (cpu_b - cpu_a) / (wall_b - wall_a):.2f} % "
              f"over {wall_b - wall_a:.1f} s (target <= 5 %)")
        print(f"file: {size / 1e6:.2f} MB = {size / 1e6 / (args.seconds / 60):.2f} MB/min; "
              f"{len(rec.ticks)} ticks recorded of {span} elapsed ({len(rec.channels)} channels)")
        print(f"droid-record said: {err}")
        print(web_rate(cell_file, min(10.0, args.seconds)))
        print(f"load average: {' '.join(f'{v:.2f}' for v in os.getloadavg())}, {os.cpu_count()} CPUs")
    finally:
        if own:
            out = droid("droid.brain.runtime.launcher", "down", "--cell", str(cell_file))
            if out.returncode != 0:
                print(f"bench_record: down failed: {out.stderr.strip()}", file=sys.stderr)


def web_rate(cell_file: Path, seconds: float) -> str:
    """droid-web on the cell: snapshots per second a WebSocket client receives, and droid-web's CPU."""
    import asyncio
    import json
    import signal
    import socket

    import aiohttp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "droid.observe.web", "--cell", str(cell_file), "--port", str(port)],
                            env=env, cwd=ROOT, stderr=subprocess.PIPE, text=True)

    async def count() -> tuple[int, float]:
        url = f"http://127.0.0.1:{port}/"
        async with aiohttp.ClientSession() as sess:
            for _ in range(100):
                try:
                    async with sess.get(url + "api/cell"):
                        break
                except aiohttp.ClientError:
                    await asyncio.sleep(0.1)
            async with sess.ws_connect(url + "ws") as ws:
                n, t0 = 0, time.monotonic()
                while time.monotonic() - t0 < seconds:
                    msg = await ws.receive(timeout=5)
                    if msg.type == aiohttp.WSMsgType.TEXT and json.loads(msg.data).get("type") == "snapshot":
                        n += 1
                return n, time.monotonic() - t0

    try:
        n, dt = asyncio.run(count())
    finally:
        proc.send_signal(signal.SIGINT)
        _, _, ru = os.wait4(proc.pid, 0)
        proc.stderr.close()
    return (f"droid-web: {n / dt:.1f} snapshots/s over its WebSocket for {dt:.1f} s (asked 30 Hz; >= 20 wanted); "
            f"its CPU incl. start-up {ru.ru_utime + ru.ru_stime:.2f} s")


def offline(args, tmp: Path) -> None:
    from droid.brain.db.databases import create_databases
    from droid.observe.mcapfile import RecordingWriter, cell_meta
    from droid.observe.record import CellRecorder
    from droid.observe.sampler import CellSampler, health
    from droid.observe.scene import scene_meta

    cell = load_cell(temp_cell(tmp, f"benchreco{os.getpid()}"))
    dbs = create_databases(cell)
    try:
        n = int(args.seconds * cell.heartbeat_hz)
        s = CellSampler(cell).connect()
        core = CellRecorder(RecordingWriter(tmp / "off.mcap", cell_meta(cell, "live", scene_meta(cell))))
        arm = [d for d in dbs if d.name.endswith("arm1.status")][0]
        t0 = time.process_time()
        for i in range(n):
            arm.update(tick=i, x=300.0 + (i % 100) * 0.37, encoder_pos=[i % 997, i % 13, 0, 0, 0, -i % 71])
            core.sample(i, i * cell.period_ns, s.read(), health_row=health(cell) if core.wants_health() else None)
        core.close()
        cpu = time.process_time() - t0
        s.close()
        per = cpu / n
        size = os.path.getsize(tmp / "off.mcap")
        print(f"offline core, {n} ticks: {per * 1e6:.0f} us/tick = {100 * per * cell.heartbeat_hz:.2f} % of one core "
              f"at {cell.heartbeat_hz:g} Hz; {size / 1e6 / (args.seconds / 60):.2f} MB/min (mostly static records)")
        import json

        from droid.observe.web import DEFAULT_RATE_HZ, LiveSource

        src = LiveSource(cell)
        m = 600
        t0 = time.process_time()
        for i in range(m):
            arm.update(tick=i, x=300.0 + (i % 100) * 0.37, encoder_pos=[i % 997, i % 13, 0, 0, 0, -i % 71])
            data = json.dumps(src.snapshot())
        per = (time.process_time() - t0) / m
        src.close()
        print(f"droid-web live snapshot (read + FK + JSON, {len(data)} B): {per * 1e6:.0f} us = "
              f"{100 * per * DEFAULT_RATE_HZ:.2f} % of one core at {DEFAULT_RATE_HZ:g} Hz")
    finally:
        for d in dbs:
            d.unlink()


def main() -> None:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=duration_s(), default=60.0, help="duration of the run [s]")
    ap.add_argument("--cell", default=None, help="a cell that is already up (default: bring the sim cell up)")
    ap.add_argument("--offline", action="store_true", help="the recording core alone, no processes")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        (offline if args.offline else live)(args, Path(d))


if __name__ == "__main__":
    main()
