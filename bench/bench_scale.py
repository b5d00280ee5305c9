#!/usr/bin/env python3
"""How many subunits does a cell carry on this host? (issue 28 item 4): prints figures, decides nothing.

For each N of ``--n`` (default 8,16,32,64) a copy of a cell file (default: the built-in
simulated cell) under a unique name gains N extra joystick subunits at ``--rate-hz``
(each: droid-joystick and droid-agent on the Brain's host, droid-remote, and a joystick
twin in droid-sim), is brought up, left idle for ``--seconds`` and brought down.  Per N:

* what ``droid-cell up`` said (its warning when the cell asks for more than the host
  can carry) and how long it took;
* missed exchanges: heartbeat ticks the tick-driven programs (remotes, agents, planner,
  serial bridge) missed in the window, summed, and the ticks a subscriber of our own
  missed;
* heartbeat lateness (p50/p99/max, from the ticks' own send times) beside the machine's
  floor measured in the same window under the same load (``cyclictest``, SCHED_FIFO
  60 Hz), and their ratio;
* the programs that said they could not keep their rate (``droid-cell status``'s
  LAGGING) and those no longer live, by name: where the cell breaks and why;
* CPU of the cell's programs summed [% of one core], the host's idle share, and
  memory (Pss, Rss summed; largest Rss).

    .venv/bin/python bench/bench_scale.py [--n 8,16,32,64] [--seconds 60] [--rate-hz 60] [--remotes one]
        [--share droid-agent,droid-joystick]

Run it alone on the machine (no other cell, no test run).  Record the printed block, with
the date and the load average it prints, in docs/benchmarks.md.
"""
from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_footprint import TICKS_PER_S, cpu_snapshot, memory_mb  # noqa: E402
from bench_footprint import make_cell as footprint_cell  # noqa: E402
from bench_under_load import TickLateness, cyclictest, droid, status_json  # noqa: E402

from droid.brain.cell.cellfile import builtin_cell_path, load_cell  # noqa: E402
from droid.cli import ArgumentParser, bounded_float  # noqa: E402


def joystick_block(k: int, rate_hz: float) -> str:
    """Subunit ``xjoyK`` and its twin: the default cell's joystick, once more."""
    return f"""
[subunits.xjoy{k}]
class = "joystick"
description = "extra joystick {k} (bench_scale)"
host = "brain"
agent = "ipc://{{run}}/xjoy{k}.agent"
relay = "ipc://{{run}}/xjoy{k}.relay"
device = "js://{{run}}/xjoy{k}.js"
rate_hz = {rate_hz}
programs = ["droid-joystick", "droid-agent"]

[world.devices.xjoy_stick{k}]
type = "joystick"
device = "{{run}}/xjoy{k}.js"
axes = 2
buttons = 8
"""


def make_cell(tmp: Path, source: Path, n: int, rate_hz: float, remotes: str = "each",
              share: tuple[str, ...] = ()) -> Path:
    """A renamed copy of ``source`` (bench_footprint's) with ``n`` extra joysticks appended,
    ``[brain] remotes`` set (``one``: one droid-remote serves every agent-linked subunit) and
    ``[cell] share`` (e.g. droid-agent, droid-joystick: one process a host for their subunits)."""
    path = footprint_cell(tmp, source)
    text = path.read_text()
    if remotes != "each":
        if "\n[brain]\n" not in text:
            raise SystemExit(f"bench_scale: {source} has no [brain] table to set remotes in")
        text = text.replace("\n[brain]\n", f'\n[brain]\nremotes = "{remotes}"\n', 1)
    if share:
        if "\n[cell]\n" not in text and not text.startswith("[cell]\n"):
            raise SystemExit(f"bench_scale: {source} has no [cell] table to set share in")
        listed = ", ".join(f'"{p}"' for p in share)
        text = text.replace("[cell]\n", f"[cell]\nshare = [{listed}]\n", 1)
    path.write_text(text + "".join(joystick_block(k, rate_hz) for k in range(n)))  # new tables
    return path


def host_idle_pct(seconds_window):
    """Share of the host's CPU time that was idle over the window [%], from /proc/stat."""
    def read():
        with open("/proc/stat") as f:
            vals = [int(x) for x in f.readline().split()[1:]]
        return sum(vals), vals[3] + vals[4]  # idle + iowait
    t0, i0 = read()
    time.sleep(seconds_window)
    t1, i1 = read()
    return 100.0 * (i1 - i0) / max(1, t1 - t0)


def one(n: int, args, tmp: Path) -> dict:
    cell = make_cell(tmp, args.cell, n, args.rate_hz, args.remotes, args.share)
    got: dict = {"n": n}
    t0 = time.monotonic()
    up = droid(cell, "droid-cell", "up", "--timeout", "240", "--force", timeout=600)  # a scale test: over the RT budget on purpose
    got["up_s"] = time.monotonic() - t0
    got["up_rc"] = up.returncode
    got["up_said"] = [ln for ln in up.stderr.splitlines() if ln.strip()]
    try:
        if up.returncode != 0:
            return got
        deadline = time.monotonic() + 60
        rows = status_json(cell)
        while time.monotonic() < deadline and not all(r["live"] for r in rows.values()):
            time.sleep(1.0)
            rows = status_json(cell)
        time.sleep(args.settle_s)
        before = status_json(cell)
        pids = {name: int(r["pid"]) for name, r in before.items() if r.get("alive")}
        got["programs"] = len(pids)
        floor: dict = {}
        ft = threading.Thread(target=lambda: floor.update(cyclictest(args.seconds) or {}))
        hb = TickLateness(load_cell(cell).heartbeat)
        hb.start()
        ft.start()
        w0 = time.monotonic()
        c0 = cpu_snapshot(pids)
        got["idle_pct"] = host_idle_pct(args.seconds)
        c1 = cpu_snapshot(pids)
        dt = time.monotonic() - w0  # the CPU window: from the first read to the last
        ft.join(args.seconds + 30)
        got["lateness"] = hb.stop()
        got["floor"] = floor.get("60Hz", {})
        after = status_json(cell)
        cpu = 0.0
        pss = rss = 0.0
        biggest = ("", 0.0)
        for name, pid in pids.items():
            try:
                cpu += (c1[name] - c0[name]) / TICKS_PER_S / dt * 100.0
                mem = memory_mb(pid)
            except (OSError, KeyError):
                continue
            pss += mem.get("Pss", 0.0)
            rss += mem.get("Rss", 0.0)
            if mem.get("Rss", 0.0) > biggest[1]:
                biggest = (name, mem["Rss"])
        got.update(cpu_pct=cpu, pss_mb=pss, rss_mb=rss, biggest=biggest)
        missed = 0
        for name, r in after.items():
            b = before.get(name)
            if b and r.get("last_tick") and r.get("overruns") is not None and b.get("overruns") is not None:
                missed += int(r["overruns"]) - int(b["overruns"])
        got["missed_exchanges"] = missed
        got["lagging"] = sorted(f"{name} ({r['missed_pct']:.0f} %)" for name, r in after.items()
                                if r.get("lagging"))
        got["not_live"] = sorted(name for name, r in after.items() if not r.get("live"))
        return got
    finally:
        down = droid(cell, "droid-cell", "down", timeout=300)
        got["down_rc"] = down.returncode


def show(g: dict, seconds: float) -> None:
    print(f"\n== default cell + {g['n']} joysticks ==")
    print(f"  droid-cell up: exit {g['up_rc']} in {g['up_s']:.1f} s")
    for ln in g["up_said"]:
        print(f"    said: {ln}")
    if g["up_rc"] != 0:
        return
    lat, fl = g.get("lateness") or {}, g.get("floor") or {}
    print(f"  programs {g['programs']}, window {seconds:.0f} s")
    print(f"  missed exchanges (tick-driven programs, summed) {g['missed_exchanges']}; "
          f"ticks our subscriber missed {lat.get('missed', '?')}")
    if lat:
        print(f"  heartbeat lateness  p50 {lat['p50']:7.0f} us  p99 {lat['p99']:7.0f} us  max {lat['max']:7.0f} us")
    if not fl:
        print("  floor: cyclictest unavailable (scripts/rt-tests.sh installs Debian's rt-tests)")
    else:
        print(f"  floor (cyclictest)  p50 {fl['p50']:7.0f} us  p99 {fl['p99']:7.0f} us  max {fl['max']:7.0f} us")
    if lat and fl:
        print(f"  heartbeat / floor   p99 {lat['p99'] / max(fl['p99'], 1.0):.1f}x  max {lat['max'] / max(fl['max'], 1.0):.1f}x")
    print(f"  CPU of the cell {g['cpu_pct']:.0f} % of one core; host idle {g['idle_pct']:.0f} %")
    print(f"  memory: Pss {g['pss_mb']:.0f} MB, Rss {g['rss_mb']:.0f} MB summed; largest Rss "
          f"{g['biggest'][0]} {g['biggest'][1]:.0f} MB")
    print(f"  lagging: {', '.join(g['lagging']) or 'none'}")
    print(f"  not live at the end: {', '.join(g['not_live']) or 'none'}")


def main() -> int:
    ap = ArgumentParser(prog="bench_scale", description=__doc__.split("\n")[0])
    ap.add_argument("--cell", type=Path, default=builtin_cell_path(), help="cell file to copy (default: built-in)")
    ap.add_argument("--n", default="8,16,32,64", help="extra joystick subunits, comma-separated")
    ap.add_argument("--seconds", type=bounded_float(5.0, 3600.0), default=60.0, help="measuring window [s]")
    ap.add_argument("--settle-s", type=bounded_float(0.0, 600.0), default=5.0,
                    help="wait after every program is live, before the window [s]")
    ap.add_argument("--rate-hz", type=bounded_float(1.0, 1000.0), default=60.0,
                    help="the extra joysticks' rate [Hz]")
    ap.add_argument("--remotes", choices=("each", "one"), default="each",
                    help="[brain] remotes: one droid-remote a subunit (each) or one for all (one)")
    ap.add_argument("--share", default="",
                    help="[cell] share: programs run once a host for all its subunits, comma-separated "
                         "(e.g. droid-agent,droid-joystick)")
    args = ap.parse_args()
    args.share = tuple(p.strip() for p in args.share.split(",") if p.strip())
    try:
        ns = [int(x) for x in args.n.split(",") if x.strip()]
    except ValueError:
        ap.error(f"--n takes whole numbers separated by commas, not {args.n!r}")
    if not ns or min(ns) < 0:
        ap.error("--n needs at least one count >= 0")
    print(f"bench_scale: {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, {os.cpu_count()} CPUs, "
          f"load average {' '.join(open('/proc/loadavg').read().split()[:3])}, cell {args.cell.name}, "
          f"remotes {args.remotes}, share {','.join(args.share) or 'none'}")
    with tempfile.TemporaryDirectory(prefix="droid-scale-") as d:
        for n in ns:
            g = one(n, args, Path(d))
            show(g, args.seconds)
            print(f"  (load average after: {' '.join(open('/proc/loadavg').read().split()[:3])})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
